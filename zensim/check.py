"""`zensim check --service sim`: exit 0 when the service's liveliness token is seen.

Used as the compose healthcheck and by scripts that wait for a stack to be up.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Annotated, ClassVar

import msgspec

from zensim.common.entry import fail
from zensim.common.session import StartupError, open_session
from zensim.common.settings import ZenohSettings, settings_or_exit
from zensim.schemas import Keys
from zensim.schemas.topics import ROUTER_ALIVE


class CheckSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim check`."""

    env_prefix: ClassVar[str] = "CHECK"
    service: str = "sim"
    """Service whose liveliness token to look for (sim, bridge, viz, router, unitree, ros1)."""
    robot_id: str = "g1"
    """Robot id (a router serves every robot: `--service router` finds it whatever the id)."""
    timeout_s: Annotated[float, msgspec.Meta(ge=0.1, le=3600)] = 5.0
    """Give up after this long."""
    zenoh: ZenohSettings = ZenohSettings()
    """Zenoh settings."""


def is_alive(session, key: str, timeout_s: float) -> bool:
    """Whether a liveliness token on `key` is seen within `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        replies = session.liveliness().get(key, timeout=max(0.1, min(1.0, remaining)))
        if any(reply.ok is not None for reply in replies):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.1)


def alive_key(service: str, robot_id: str) -> str:
    """The token that says `service` is up for `robot_id`.

    The router serves every robot: it announces `zensim/@router/alive` whatever id it was started
    with (its `alive/router` names only that one id), so a check for another robot still finds it.
    """
    if service == "router":
        return ROUTER_ALIVE.full_key()
    return Keys(robot_id).alive(service)


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(CheckSettings, argv, "zensim check")
    key = alive_key(settings.service, settings.robot_id)
    started = time.monotonic()
    try:  # the whole check, the session's open included, keeps to --timeout-s
        session = open_session(settings.zenoh, claim_meeting_point=False, timeout_s=settings.timeout_s)
    except StartupError as exc:
        return fail("zensim check", str(exc))
    with session:
        alive = is_alive(session, key, max(0.1, settings.timeout_s - (time.monotonic() - started)))
    print(f"{key}: {'alive' if alive else 'not seen'}")
    return 0 if alive else 1
