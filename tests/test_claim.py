"""One robot id, one source of its states (services/common/claim.py), on a real router: claims are atomic
(two sims started at the same moment with one id: one runs) and ignore wildcard tokens (one credential's
`zensim/*/alive/sim` once kept every sim on the router from starting)."""

from __future__ import annotations

import threading

from support import Latest, plain_client, wait_for
from zensim.common.claim import RIVAL, current_owner
from zensim.schemas import Keys, SimStatus


def race(endpoint: str, keys: Keys, claimers: int) -> list[str | None]:
    """`claimers` sessions call current_owner for one id at the same moment; what each got."""
    sessions = [plain_client(endpoint) for _ in range(claimers)]
    results: list[str | None] = [""] * claimers
    barrier = threading.Barrier(claimers)

    def claim(i: int) -> None:
        barrier.wait()
        results[i] = current_owner(sessions[i], keys)

    threads = [threading.Thread(target=claim, args=(i,)) for i in range(claimers)]
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(60)
    finally:
        for session in sessions:
            session.close()
    return results


def test_claimers_at_the_same_moment_one_wins(router_endpoint, robot_id) -> None:
    """Ten rounds of three claimers released by one barrier: exactly one of each round holds the id (the
    old check-then-act let all three through every time); the others name a rival or the winner."""
    for round_ in range(10):
        results = race(router_endpoint, Keys(f"{robot_id}-{round_}"), 3)
        assert results.count(None) == 1, results
        assert all(result in (RIVAL, None) for result in results), results


def test_a_held_claim_keeps_a_later_claimer_out_until_its_session_closes(router_endpoint, robot_id) -> None:
    keys = Keys(robot_id)
    with plain_client(router_endpoint) as first:
        assert current_owner(first, keys) is None
        with plain_client(router_endpoint) as second:
            assert current_owner(second, keys) == RIVAL
    with plain_client(router_endpoint) as third:
        assert current_owner(third, keys) is None


def test_wildcard_tokens_are_not_owners(router_endpoint, robot_id) -> None:
    """A token on `zensim/*/alive/sim` (or on `claim/*`) matches every id's query but serves no robot."""
    with plain_client(router_endpoint) as squatter, plain_client(router_endpoint) as claimer:
        tokens = [squatter.liveliness().declare_token(key) for key in
                  ("zensim/*/alive/sim", "zensim/*/alive/world", "zensim/**", f"zensim/{robot_id}/claim/*")]
        try:
            wait_declared(claimer, f"zensim/{robot_id}/alive/sim")
            assert current_owner(claimer, Keys(robot_id)) is None
        finally:
            for token in tokens:
                token.undeclare()


def wait_declared(session, key: str) -> None:
    """Until the router answers a liveliness query for `key` (the squatter's tokens have propagated)."""
    wait_for(lambda: any(r.ok is not None for r in session.liveliness().get(key, timeout=1.0)), 10,
             f"a token matching {key}")


def test_two_sims_started_at_once_with_one_id_one_runs(start_service, zsession, robot_id) -> None:
    """The user-visible race: `zensim sim` twice at the same moment. One serves the id; the other exits 2
    and says who holds it."""
    count = 2
    sims = [start_service("sim", "--mode", "fixed") for _ in range(count)]
    Latest(zsession, Keys(robot_id).sim_status, SimStatus).wait(what="a sim's status", timeout_s=60)
    wait_for(lambda: sum(sim.alive() for sim in sims) <= 1, 30, "the second sim to step back")
    running = [sim for sim in sims if sim.alive()]
    stopped = [sim for sim in sims if not sim.alive()]
    assert len(running) == 1 and len(stopped) == count - 1, [s.log()[-2000:] for s in sims]
    for sim in stopped:
        assert sim.proc.returncode == 2 and "already served by" in sim.log(), sim.log()
