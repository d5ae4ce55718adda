"""`zensim unitree` entry point: load settings, set up logging, run the service."""

from __future__ import annotations

import sys
from collections.abc import Sequence

import logging

from zensim.common.edges import check_edge
from zensim.common.entry import StartupError, fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import settings_or_exit

from zensim.common.ddsbind import is_loopback
from .settings import UnitreeSettings

PROG = "zensim unitree"


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(UnitreeSettings, argv, PROG)
    setup_logging(settings.log_level)
    try:  # DDS has no authentication: loopback unless asked (docs/security.md)
        check_edge("the Unitree DDS adapter", f"interface {settings.interface or '(any: Cyclone DDS chooses)'}",
                   is_loopback(settings.interface), settings.zenoh.secure_dir, settings.open_edge,
                   logging.getLogger("zensim.unitree"))
    except StartupError as exc:
        return fail(PROG, str(exc))
    try:
        from .service import run  # imports cyclonedds: say how to get it when it is missing
    except ImportError as exc:
        return fail(PROG, f"cannot load Cyclone DDS ({exc}): install it with scripts/install-cyclonedds "
                          "(see docs/unitree.md)")
    # Its own role in a secured setup (schemas/topics.py ROLES, docs/security.md): cmd/motors like the
    # bridge, and its own state/unitree and alive/unitree.
    return serve(PROG, settings, run, role="unitree")


if __name__ == "__main__":
    sys.exit(main())
