"""`zensim ros2` entry point: load settings, set up logging, run the ROS 2 face."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.entry import serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import Ros2Settings

PROG = "zensim ros2"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(Ros2Settings, argv, PROG)
    setup_logging(settings.log_level)
    from .service import run

    # The face sends what the bridge's clients send (cmd/joints) and reads what they read: its own role
    # in a secured setup (docs/security.md).
    # zenoh-ext's advanced publisher (the cache a late ROS 2 subscription reads latched topics from, as
    # rmw_zenoh's do) orders its samples by timestamp: the session must stamp them.
    return serve(PROG, settings, run, role="ros2", extra_config={"timestamping/enabled": True})


if __name__ == "__main__":
    sys.exit(main())
