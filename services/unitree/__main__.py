"""`zensim unitree` entry point: load settings, set up logging, run the service."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from zensim.common.logs import setup_logging
from zensim.common.session import open_session
from zensim.common.settings import describe, settings_or_exit
from zensim.common.shutdown import stop_on_signals

from .settings import UnitreeSettings

logger = logging.getLogger("zensim.unitree")


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(UnitreeSettings, argv, "zensim unitree")
    setup_logging(settings.log_level)
    try:
        from .service import run  # imports cyclonedds: say how to get it when it is missing
    except ImportError as exc:
        logger.error("cannot load Cyclone DDS (%s): install it with scripts/install-cyclonedds "
                     "(see docs/unitree.md)", exc)
        return 2
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))
    with open_session(settings.zenoh) as session:
        code = run(session, settings, stop)
    logger.info("unitree adapter stopped")
    return code


if __name__ == "__main__":
    sys.exit(main())
