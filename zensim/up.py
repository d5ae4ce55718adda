"""`zensim up`: router, sim, bridge and viz as local processes, for a machine without Docker.

The same four services as compose.yaml, wired the same way: a router listens
on one endpoint and the others join it as clients with multicast scouting off.
Ctrl-C (or SIGTERM) stops them all, newest first, and waits for each; if any
service dies on its own, the rest are stopped too and the exit code says so.
Extra `ZENSIM_*` variables in the environment reach every service (e.g.
`ZENSIM_MODE=fixed zensim up`).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

import msgspec

from zensim.common.logs import setup_logging
from zensim.common.settings import describe, settings_or_exit
from zensim.common.shutdown import stop_on_signals
from zensim.schemas.keys import SERVICES

logger = logging.getLogger("zensim.up")

STOP_TIMEOUT_S = 10.0


class UpSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim up`."""

    router_endpoint: str = "tcp/127.0.0.1:7447"
    """Where the router listens and the other services connect."""
    viz: bool = True
    """Also run the web viewer."""
    log_level: str = "INFO"
    """Python log level of `zensim up` itself (the services follow ZENSIM_LOG_LEVEL)."""


def service_env(name: str, endpoint: str) -> dict[str, str]:
    env = dict(os.environ, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    if name == "router":
        env.update(ZENSIM_ZENOH_MODE="router", ZENSIM_ZENOH_LISTEN=endpoint)
        env.pop("ZENSIM_ZENOH_CONNECT", None)
    else:
        env.update(ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint)
        env.pop("ZENSIM_ZENOH_LISTEN", None)
    return env


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(UpSettings, argv, "zensim up")
    setup_logging(settings.log_level)
    logger.info("starting: %s", describe(settings))
    # Start the children before anything opens a zenoh session (fork after zenoh.open hangs).
    names = [name for name in SERVICES if settings.viz or name != "viz"]
    procs: dict[str, subprocess.Popen] = {}
    stop = stop_on_signals()
    for name in names:
        # Own process group: a terminal's Ctrl-C reaches only us, and we stop the children in order.
        procs[name] = subprocess.Popen(
            [sys.executable, "-m", "zensim", name],
            env=service_env(name, settings.router_endpoint),
            start_new_session=True,
        )
        logger.info("started %s (pid %d)", name, procs[name].pid)
    exit_code = 0
    while not stop.is_set():
        dead = {name: p.returncode for name, p in procs.items() if p.poll() is not None}
        if dead:
            logger.error("service(s) exited: %s; stopping the rest", dead)
            exit_code = 1
            break
        stop.wait(0.2)
    for name in reversed(names):
        proc = procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for name in reversed(names):
        proc = procs[name]
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            logger.warning("%s did not stop in time: killing it", name)
            proc.kill()
            proc.wait()
            exit_code = 1
        logger.info("%s exited with %s", name, proc.returncode)
    return exit_code
