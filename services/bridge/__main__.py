"""`zensim bridge` entry point: load settings, set up logging, run the service."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from zensim.common.logs import setup_logging
from zensim.common.session import open_session
from zensim.common.settings import describe, settings_or_exit
from zensim.common.shutdown import stop_on_signals

from .service import run
from .settings import BridgeSettings

logger = logging.getLogger("zensim.bridge")


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(BridgeSettings, argv, "zensim bridge")
    setup_logging(settings.log_level)
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))
    with open_session(settings.zenoh, role="bridge") as session:
        code = run(session, settings, stop)
    logger.info("bridge stopped")
    return code


if __name__ == "__main__":
    sys.exit(main())
