"""`zensim sim` / `python -m zensim.sim`: load settings, set up logging, run the service."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import SimSettings


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(SimSettings, argv, "zensim sim")
    setup_logging(settings.log_level)
    from zensim.robots.builder import RobotModelError

    from .service import run  # imports mujoco: only after the settings parsed

    try:
        return run(settings)
    except RobotModelError as exc:
        # A description the sim will not load (e.g. a mesh outside its folder): one line, not a traceback.
        print(f"zensim sim: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
