"""`zensim sim` / `python -m zensim.sim`: load settings, set up logging, build the world, serve."""

from __future__ import annotations

import functools
import sys
from collections.abc import Sequence

from zensim.common.entry import StartupError, fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from .settings import SimSettings

PROG = "zensim sim"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(SimSettings, argv, PROG)
    setup_logging(settings.log_level)
    from .service import load_world, run  # imports mujoco: only after the settings parsed

    try:
        world, world_file = load_world(settings)  # before the session: a bad robot or world file fails fast
    except StartupError as exc:
        return fail(PROG, str(exc))
    return serve(PROG, settings, functools.partial(run, world=world, world_file=world_file), role="sim")


if __name__ == "__main__":
    sys.exit(main())
