"""`zensim robot ...`: build a robot's completed MJCF and inspect its joints, limits and gains.

`zensim robot build g1 --mode floating -o DIR` writes `<name>_<mode>.xml` (the MJCF the simulator
compiles) and `<name>_<mode>_control.toml` (gains, pose and limits resolved per joint): the
counterparts of the ROS seed's generated g1_complete.urdf and controllers.yaml.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

import msgspec

from zensim.robots import DEFAULT_ROBOT, robot_files
from zensim.robots.builder import MODES, Robot, build, build_with_mjcf
from zensim.robots.control import ControlConfigError

logger = logging.getLogger(__name__)


class ResolvedJoint(msgspec.Struct, frozen=True, kw_only=True):
    """One joint's resolved figures (rad, N m, rad/s; gains per the mode)."""

    name: str
    q_min: float
    q_max: float
    effort_limit: float
    velocity_limit: float
    default_q: float
    kp: float
    kd: float
    armature: float


class ResolvedControl(msgspec.Struct, frozen=True, kw_only=True):
    """What `build` made of the URDF and control.toml for one mode."""

    robot: str
    mode: str
    urdf: str
    control: str
    base_height_m: float
    timestep_s: float
    joints: list[ResolvedJoint]


def resolved_control(robot: Robot) -> ResolvedControl:
    """Summarise a built robot per joint, in canonical order."""
    joints = [
        ResolvedJoint(name=n, q_min=float(robot.q_min[i]), q_max=float(robot.q_max[i]),
                      effort_limit=float(robot.effort_limit[i]), velocity_limit=float(robot.velocity_limit[i]),
                      default_q=float(robot.default_q[i]), kp=float(robot.kp[i]), kd=float(robot.kd[i]),
                      armature=float(robot.armature[i]))
        for i, n in enumerate(robot.joint_names)
    ]
    return ResolvedControl(robot=robot.name, mode=robot.mode, urdf=str(robot.urdf_path),
                           control=str(robot.control_path) if robot.control_path else "(defaults)",
                           base_height_m=robot.base_height_m, timestep_s=float(robot.model.opt.timestep),
                           joints=joints)


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    return msgspec.json.encode(str(value)).decode()  # a JSON string is a valid TOML basic string


def to_toml(summary: ResolvedControl) -> str:
    """Write the summary as TOML by hand: msgspec's TOML encoder needs tomli_w, which we do not ship."""
    data = msgspec.to_builtins(summary)
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if k != "joints"]
    for joint in data["joints"]:
        lines += ["", "[[joints]]"] + [f"{k} = {_toml_value(v)}" for k, v in joint.items()]
    return "\n".join(lines) + "\n"


def _table(robot: Robot) -> str:
    lines = [f"{robot.name} ({robot.mode}): {robot.nu} joints, base height {robot.base_height_m:.3f} m, "
             f"dt {robot.model.opt.timestep * 1e3:g} ms",
             f"  urdf:    {robot.urdf_path}", f"  control: {robot.control_path or '(defaults)'}",
             f"  {'#':>2} {'joint':28} {'q_min':>8} {'q_max':>8} {'effort':>7} {'vel':>6} {'q0':>6} "
             f"{'kp':>7} {'kd':>6} {'armature':>8}"]
    for i, n in enumerate(robot.joint_names):
        lines.append(f"  {i:2d} {n:28} {robot.q_min[i]:8.4f} {robot.q_max[i]:8.4f} {robot.effort_limit[i]:7.1f} "
                     f"{robot.velocity_limit[i]:6.1f} {robot.default_q[i]:6.2f} {robot.kp[i]:7.1f} "
                     f"{robot.kd[i]:6.2f} {robot.armature[i]:8.4f}")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="zensim robot", description="Build and inspect robot models.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help_text in (("build", "write the completed MJCF and the resolved control summary"),
                            ("info", "print joints, limits and gains")):
        p = sub.add_parser(name, help=help_text)
        p.add_argument("robot", nargs="?", default=None,
                       help=f"bundled robot (default {DEFAULT_ROBOT} unless --urdf is given); alias g1")
        p.add_argument("--mode", choices=MODES, default="floating")
        p.add_argument("--urdf", type=Path, help="use this URDF instead of the bundled one")
        p.add_argument("--control", type=Path, help="use this control.toml")
        if name == "build":
            p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    return parser


def main(argv: list[str]) -> int:
    """Entry point of `zensim robot`; returns the process exit code (2 for bad input)."""
    args = _parser().parse_args(argv)
    try:
        files = robot_files(args.robot, urdf=args.urdf, control=args.control)
        robot, mjcf = build_with_mjcf(files, args.mode) if args.command == "build" else (build(files, args.mode), "")
    except (FileNotFoundError, ValueError) as exc:  # ControlConfigError/RobotModelError are ValueErrors
        sys.stderr.write(f"zensim robot: {exc}\n")
        return 2
    if args.command == "info":
        sys.stdout.write(_table(robot) + "\n")
        return 0
    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{robot.name}_{args.mode}"
    mjcf_path, control_path = out / f"{stem}.xml", out / f"{stem}_control.toml"
    mjcf_path.write_text(mjcf)
    header = (f"# Resolved by `zensim robot build` from {files.urdf} and {files.control or '(defaults)'}.\n"
              "# Informational: the simulator reads the URDF and control.toml, not this file.\n")
    control_path.write_text(header + to_toml(resolved_control(robot)))
    sys.stdout.write(f"wrote {mjcf_path}\nwrote {control_path}\n")
    return 0


__all__ = ["ControlConfigError", "main", "resolved_control", "to_toml"]
