"""`zensim loco` entry point: load settings, set up logging, run the service."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.entry import serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import LocoSettings

PROG = "zensim loco"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(LocoSettings, argv, PROG)
    setup_logging(settings.log_level)
    from .service import run  # numpy and the policy load only for a real run, not for --help

    return serve(PROG, settings, run, role="loco")


if __name__ == "__main__":
    sys.exit(main())
