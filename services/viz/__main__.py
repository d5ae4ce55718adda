"""`zensim viz` / `python -m zensim.viz`: load settings, set up logging, run the service."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from zensim.common.logs import setup_logging
from zensim.common.session import open_session
from zensim.common.settings import describe, settings_or_exit
from zensim.common.shutdown import stop_on_signals

from .settings import VizSettings

logger = logging.getLogger("zensim.viz")


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(VizSettings, argv, "zensim viz")
    if len(settings.ghost_offset_m) != 3:
        print("zensim viz: --ghost-offset-m needs three numbers x,y,z", file=sys.stderr)
        return 2
    setup_logging(settings.log_level)
    stop = stop_on_signals()
    logger.info("starting: %s", describe(settings))
    from .service import run  # imports tornado and meshcat: only after the settings parsed

    with open_session(settings.zenoh, role="viz") as session:
        code = run(session, settings, stop)
    logger.info("session closed")
    return code


if __name__ == "__main__":
    sys.exit(main())
