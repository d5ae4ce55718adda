"""`zensim ros1` entry point: find rospy, load settings, set up logging, run the gateway."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.entry import StartupError, fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import Ros1Settings

PROG = "zensim ros1"


def import_rospy(fallback_path: str) -> str | None:
    """Make rospy importable; returns why not, or None.

    ROS 1 comes from the system's packages (Debian's python3-rospy), not from PyPI, so a virtual
    environment does not see it. When the running Python cannot import rospy, the folder the
    system's Python keeps it in is searched too, after every other folder: the project's own
    packages (numpy, yaml, ...) still come first, only what is missing comes from there.
    """
    try:
        import rospy  # noqa: F401
        return None
    except ImportError as exc:
        first_error = exc
    if fallback_path and fallback_path not in sys.path:
        sys.path.append(fallback_path)
    try:
        import rospy  # noqa: F401, F811
        return None
    except ImportError as exc:
        return str(exc) if fallback_path else str(first_error)


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(Ros1Settings, argv, PROG)
    setup_logging(settings.log_level)
    missing = import_rospy(settings.ros_python_path)
    if missing:
        return fail(PROG, f"cannot import rospy ({missing}): install ROS 1 (Debian: apt-get install python3-rospy "
                          "python3-sensor-msgs python3-nav-msgs python3-rosgraph-msgs python3-tf2-msgs) or point "
                          "--ros-python-path at the folder that holds rospy (see docs/ros.md)")
    from .service import check_ros_edge, run

    try:  # ROS 1 has no authentication: loopback unless asked (docs/security.md)
        check_ros_edge(settings)
    except StartupError as exc:
        return fail(PROG, str(exc))

    # The gateway sends what the bridge's clients send (cmd/joints, cmd/joint/*) and reads what they
    # read: its own role in a secured setup (docs/security.md).
    return serve(PROG, settings, run, role="ros1")


if __name__ == "__main__":
    sys.exit(main())
