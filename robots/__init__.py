"""Robot descriptions bundled with zensim and how to locate them.

A robot is a URDF plus an optional control.toml (gains, pose, armature, solver settings). Bundled
robots live in one folder each (`robots/<maker>_<model>/`); any other URDF, including Unitree's own
g1_description checkout with its meshes, is loaded the same way through `robot_files(urdf=...)`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

__all__ = ["BUNDLED_DIR", "DEFAULT_ROBOT", "ROBOT_ALIASES", "RobotFiles", "bundled_robots", "robot_files"]

DEFAULT_ROBOT: Final = "unitree_g1"
BUNDLED_DIR: Final = Path(__file__).resolve().parent
ROBOT_ALIASES: Final[dict[str, str]] = {"g1": "unitree_g1"}
CONTROL_FILE: Final = "control.toml"


@dataclass(frozen=True)
class RobotFiles:
    """The files that define one robot. Mesh paths in the URDF resolve relative to its folder."""

    urdf: Path
    control: Path | None


def bundled_robots() -> list[str]:
    """Names of the robot folders shipped with the package (those holding a URDF)."""
    return sorted(p.name for p in BUNDLED_DIR.iterdir() if p.is_dir() and any(p.glob("*.urdf")))


def _bundled_dir(robot: str) -> Path:
    name = ROBOT_ALIASES.get(robot, robot)
    folder = BUNDLED_DIR / name
    if not folder.is_dir() or not any(folder.glob("*.urdf")):
        known = ", ".join(bundled_robots() + sorted(ROBOT_ALIASES))
        raise FileNotFoundError(f"unknown robot {robot!r}; bundled robots: {known}")
    return folder


def robot_files(robot: str | None = None, urdf: str | Path | None = None, control: str | Path | None = None) -> RobotFiles:
    """Locate a robot's URDF and control file.

    Precedence: an explicit `urdf`/`control` wins over the bundled robot's files. So
    `robot_files("g1", urdf=official)` runs Unitree's own URDF with the project's G1 gains, while
    `robot_files(urdf=official)` alone takes a control.toml beside that URDF, or the defaults.

    Args:
        robot: A bundled folder name ("unitree_g1", alias "g1"). Defaults to DEFAULT_ROBOT when
            `urdf` is also None.
        urdf: Any URDF file.
        control: A control.toml; defaults to the bundled robot's, else control.toml beside the URDF
            when present, else None (defaults).

    Returns:
        Absolute paths.

    Raises:
        FileNotFoundError: An unknown robot name or a missing file.
    """
    folder = _bundled_dir(robot if robot is not None else DEFAULT_ROBOT) if robot is not None or urdf is None else None
    if urdf is not None:
        urdf_path = Path(urdf).expanduser().resolve()
    else:
        assert folder is not None
        urdf_path = sorted(folder.glob("*.urdf"))[0]
    if not urdf_path.is_file():
        raise FileNotFoundError(f"URDF not found: {urdf_path}")
    if control is not None:
        given = Path(control).expanduser().resolve()
        if not given.is_file():
            raise FileNotFoundError(f"control file not found: {given}")
        return RobotFiles(urdf=urdf_path, control=given)
    candidates = ([folder / CONTROL_FILE] if folder is not None else []) + [urdf_path.parent / CONTROL_FILE]
    return RobotFiles(urdf=urdf_path, control=next((c for c in candidates if c.is_file()), None))
