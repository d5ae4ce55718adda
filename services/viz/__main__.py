"""`zensim viz` / `python -m zensim.viz`: load settings, set up logging, run the service."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from zensim.common.entry import fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import VizSettings

PROG = "zensim viz"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(VizSettings, argv, PROG)
    if len(settings.ghost_offset_m) != 3:
        return fail(PROG, "--ghost-offset-m needs three numbers x,y,z")
    setup_logging(settings.log_level)
    from .service import run  # imports tornado and meshcat: only after the settings parsed

    return serve(PROG, settings, run, role="viz")


if __name__ == "__main__":
    sys.exit(main())
