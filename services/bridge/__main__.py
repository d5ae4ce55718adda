"""`zensim bridge` entry point: load settings, set up logging, run the service."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.entry import serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .service import run
from .settings import BridgeSettings

PROG = "zensim bridge"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(BridgeSettings, argv, PROG)
    setup_logging(settings.log_level)
    return serve(PROG, settings, run, role="bridge")


if __name__ == "__main__":
    sys.exit(main())
