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
    from .service import run  # imports mujoco: only after the settings parsed

    return run(settings)


if __name__ == "__main__":
    sys.exit(main())
