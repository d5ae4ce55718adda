"""`zensim sim` / `python -m zensim.sim`: load settings, set up logging, build the robot, serve."""

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
    from .service import load_simulation, run  # imports mujoco: only after the settings parsed

    if settings.world:  # several robots in one world (world.py)
        from .world import load_world, run_world

        try:
            world = load_world(settings)
        except StartupError as exc:
            return fail(PROG, str(exc))
        return serve(PROG, settings, functools.partial(run_world, world=world), role="sim")
    try:
        sim = load_simulation(settings)  # before the session: a bad robot file fails fast
    except StartupError as exc:
        return fail(PROG, str(exc))
    return serve(PROG, settings, functools.partial(run, sim=sim), role="sim")


if __name__ == "__main__":
    sys.exit(main())
