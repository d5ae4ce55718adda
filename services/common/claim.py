"""One robot id, one source of its states: a sim or a replay refuses an id that another already serves.

Two publishers of `state/*` under one id collide silently (sim time runs backwards, the bridge
re-learns the robot over and over and drops its targets). Both the sim and `zensim replay` declare
`alive/sim` (a replay also `alive/replay`), so one liveliness query at startup says whether the id
is taken, and by whom.

Checking alone is check-then-act: two sims started at the same moment both see a free id and both
run. So a process first declares a claim of its own (`claim/{nonce}`, a liveliness token it keeps
while it serves) and only then looks: one that sees another's claim beside its own steps back,
waits a random moment and tries again. The router handles one session's messages in order, so
whichever of two claimers' queries reaches it second sees the other's claim: two can both step
back, never both go on (with one router; routers meshed with each other add their propagation
delay to the race). The loser of a race sees the winner's `alive/sim` on its next try and says so.

Only tokens on the exact keys count: a liveliness token on a wildcard (`zensim/*/alive/sim`, which
any credential allowed `alive/sim` may declare) matches every id's query but serves no robot.
"""

from __future__ import annotations

import random
import secrets
import threading
import time

import zenoh

from zensim.common.wire import is_wildcard
from zensim.schemas import Keys

CLAIM_CHECK_S = 1.0
"""How long the startup check waits for the router's answer (it answers at once on a healthy network)."""
OWNERS = ("replay", "sim", "world")
"""Tokens that mean "this id is already served", most specific first (a world's own id carries alive/world:
its verbs live under it, so neither a second world nor a robot may take it)."""
CLAIM_TRIES = 6
"""Tries before a process that keeps meeting other claims (and no owner) gives up."""
BACKOFF_S = (0.05, 0.4)
"""Range of the random wait between tries: two rivals rarely draw the same moment twice."""
RIVAL = "claim"
"""The owner `current_owner` names when only other processes' claims were seen (they are starting)."""

_held: list[zenoh.LivelinessToken] = []
"""The claims this process won: a token is undeclared when dropped, so they are kept here until their
session closes (which undeclares them)."""
_held_lock = threading.Lock()


def current_owner(session: zenoh.Session, keys: Keys) -> str | None:
    """`replay`, `sim` or `world` when one already serves this id, `claim` when others are starting
    with it, else None: then this session holds the id's claim until it closes.

    Blocks up to about CLAIM_TRIES * (CLAIM_CHECK_S + the longest backoff) when rivals keep appearing;
    a free id takes one round trip to the router.
    """
    for attempt in range(CLAIM_TRIES):
        nonce = secrets.token_hex(8)
        token = session.liveliness().declare_token(keys.claim(nonce))
        owner, rivals = _seen(session, keys, nonce)
        if owner is None and not rivals:
            with _held_lock:
                _held.append(token)
            return None
        token.undeclare()
        if owner is not None:
            return owner
        if attempt + 1 < CLAIM_TRIES:
            time.sleep(random.uniform(*BACKOFF_S))
    return RIVAL


def _seen(session: zenoh.Session, keys: Keys, nonce: str) -> tuple[str | None, int]:
    """The most specific owner token on this id's exact keys, and how many other claims are up."""
    found: set[str] = set()
    rivals: set[str] = set()
    own = keys.claim(nonce)
    owner_keys = {keys.alive(owner): owner for owner in OWNERS}
    for pattern in (keys.alive("*"), keys.claim("*")):
        for reply in session.liveliness().get(pattern, timeout=CLAIM_CHECK_S):
            if reply.ok is None or is_wildcard(reply.ok.key_expr):
                continue
            key = str(reply.ok.key_expr)
            if key in owner_keys:
                found.add(owner_keys[key])
            elif key != own and key.startswith(keys.claim("")):
                rivals.add(key)
    return next((owner for owner in OWNERS if owner in found), None), len(rivals)


def taken_message(robot_id: str, owner: str) -> str:
    """The one line a refused sim or replay prints."""
    who = {"replay": "a `zensim replay`", "world": "a world (`zensim sim --world`) as its own id",
           RIVAL: "another sim or replay starting with it at the same moment"}.get(owner, "a live sim")
    token = "a claim/* token" if owner == RIVAL else f"its alive/{owner} token"
    return (f"robot id {robot_id!r} is already served by {who} ({token} is up); "
            "stop it, or use another id: --robot-id ID")
