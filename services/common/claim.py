"""One robot id, one source of its states: a sim or a replay refuses an id that another already serves.

Two publishers of `state/*` under one id collide silently (sim time runs backwards, the bridge
re-learns the robot over and over and drops its targets). Both the sim and `zensim replay` declare
`alive/sim` (a replay also `alive/replay`), so one liveliness query at startup says whether the id
is taken, and by whom.
"""

from __future__ import annotations

import zenoh

from zensim.schemas import Keys

CLAIM_CHECK_S = 1.0
"""How long the startup check waits for the router's answer (it answers at once on a healthy network)."""
OWNERS = ("replay", "sim", "world")
"""Tokens that mean "this id is already served", most specific first (a world's own id carries alive/world:
its verbs live under it, so neither a second world nor a robot may take it)."""


def current_owner(session: zenoh.Session, keys: Keys) -> str | None:
    """`replay`, `sim` or `world` when one already serves this id, else None."""
    found: set[str] = set()
    for reply in session.liveliness().get(keys.alive("*"), timeout=CLAIM_CHECK_S):
        if reply.ok is not None:
            found.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return next((owner for owner in OWNERS if owner in found), None)


def taken_message(robot_id: str, owner: str) -> str:
    """The one line a refused sim or replay prints."""
    who = {"replay": "a `zensim replay`", "world": "a world (`zensim sim --world`) as its own id"}.get(owner, "a live sim")
    return (f"robot id {robot_id!r} is already served by {who} (its alive/{owner} token is up); "
            "stop it, or use another id: --robot-id ID")
