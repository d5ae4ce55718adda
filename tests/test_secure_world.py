"""Per-robot roles inside a world (issue 26 item 3), on a real secured router.

Two named operators (`zensim secure init --client op-a=operator:a --client op-b=operator:b`) drive one
lockstep world of two fixed G1s, each its own robot: op-a's commands, resets, pauses and advances of
robot `b` are refused (by the router on `b`'s and the world's keys; by the sim on `a`'s own key, counted in
`a`'s status and answered), and `b`'s elbow stays where it was while `a`'s moves; op-b drives `b` the same
way. The unscoped operator still advances both robots through the world's key and pauses the world.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from support import Latest, Service, free_port, wait_for
from test_secure import role_conf
from zensim.schemas import JointState, Keys, SimStatus

WORLD, A, B = "lab", "a", "b"
ELBOW = "left_elbow_joint"


def advance(session: zenoh.Session, key: str, commands: dict[str, float]) -> list[dict]:
    """One world/advance request (JSON, as any client sends it): robot -> elbow target; the decoded replies."""
    payload = json.dumps({"commands": {robot: {"names": [ELBOW], "q": [q]} for robot, q in commands.items()}})
    return [json.loads(r.ok.payload.to_bytes()) if r.ok is not None else {"err": r.err.payload.to_string()}
            for r in session.get(key, payload=payload, timeout=5)]


def ask(session: zenoh.Session, key: str, payload: dict | None = None) -> list[dict]:
    return [json.loads(r.ok.payload.to_bytes()) if r.ok is not None else {"err": r.err.payload.to_string()}
            for r in session.get(key, payload=json.dumps(payload or {}), timeout=3)]


@pytest.mark.parametrize("client, says", [
    ("x=sim:a", "service's role"), ("operator=operator:a", "name is taken"), ("router=viewer", "name is taken"),
    ("Bad=operator:a", "[a-z0-9_-]"), ("x=nobody", "no role 'nobody'"), ("x=operator:BAD", "must match"),
    ("x=", "NAME=ROLE"), ("=operator", "NAME=ROLE")])
def test_init_refuses_a_bad_named_client_and_writes_nothing(tmp_path: Path, client: str, says: str) -> None:
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(tmp_path / "s"), "--client", client],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and says in done.stderr, done.stderr
    assert not (tmp_path / "s").exists()


def test_init_refuses_a_named_client_given_twice(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(tmp_path / "s"),
                           "--client", "x=operator:a", "--client", "x=viewer"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "unique" in done.stderr, done.stderr
    assert not (tmp_path / "s").exists()


@pytest.fixture
def secured_world(tmp_path: Path) -> Iterator[tuple[Path, str, Service]]:
    """A secured router with named operators op-a (robot a) and op-b (robot b), and a lockstep world of two
    fixed G1s: (secrets folder, endpoint, sim)."""
    folder = tmp_path / "secrets"
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder),
                           "--client", f"op-a=operator:{A}", "--client", f"op-b=operator:{B}"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    (tmp_path / "world.toml").write_text(
        f'id = "{WORLD}"\n[[robots]]\nid = "{A}"\nmode = "fixed"\n[[robots]]\nid = "{B}"\nmode = "fixed"\nxy = [0.0, 2.0]\n')
    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(folder), PYTHONUNBUFFERED="1")
    router = Service("router", ["--zenoh-listen", endpoint], env, tmp_path)
    sim = None
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 20, "the secured router")
        sim = Service("sim", ["--zenoh-connect", endpoint, "--world", str(tmp_path / "world.toml"),
                              "--clock", "lockstep"], env, tmp_path)
        yield folder, endpoint, sim
    finally:
        if sim is not None:
            sim.stop()
        router.stop()


def test_two_operators_each_scoped_to_one_robot_of_a_world_cannot_touch_the_other(
        secured_world: tuple[Path, str, Service]) -> None:
    folder, endpoint, sim = secured_world
    with zenoh.open(role_conf(folder, "op-a", endpoint)) as op_a, \
            zenoh.open(role_conf(folder, "op-b", endpoint)) as op_b, \
            zenoh.open(role_conf(folder, "operator", endpoint)) as operator:
        a_status = Latest(op_a, Keys(A).sim_status, SimStatus)  # what op-a sees of its own robot
        b_status = Latest(op_b, Keys(B).sim_status, SimStatus)
        b_joints = Latest(operator, Keys(B).joints, JointState)  # the unscoped operator watches b
        a_status.wait(timeout_s=90, what="robot a's status at op-a")
        b_status.wait(timeout_s=30, what="robot b's status at op-b")
        info = json.loads(next(iter(operator.get(Keys(B).robot_info + "?format=json", timeout=10))).ok.payload.to_bytes())
        elbow = info["joint_names"].index(ELBOW)
        # The unscoped operator's world/advance (the whole world's key) moves time, so b's states flow.
        first = advance(operator, Keys(WORLD).world_advance, {})
        assert first[0]["ok"] and sorted(first[0]["states"]) == [A, B], first
        b_before = b_joints.wait(lambda m: m.sim_time_s >= first[0]["sim_time_s"], what="b's state").q[elbow]
        rejected_before = a_status.value.rejected_requests

        # op-a against b: the router drops every key of b's and the world's (no reply at all) ...
        for _ in range(10):
            op_a.put(Keys(B).motors, json.dumps({"names": [ELBOW], "q": [1.2]}))
        assert ask(op_a, Keys(B).ctl("reset")) == []
        assert ask(op_a, Keys(B).ctl("pause")) == []
        assert advance(op_a, Keys(B).world_advance, {B: 1.2}) == []
        for verb in ("pause", "step", "reset"):
            assert ask(op_a, f"{Keys(WORLD).root}/world/{verb}") == [], verb
        assert advance(op_a, Keys(WORLD).world_advance, {A: 0.6, B: 1.2}) == []
        # ... and what reaches the sim on a's own keys but would move b is refused, answered and counted.
        for verb in ("pause", "step", "resume"):
            (refused,) = ask(op_a, Keys(A).ctl(verb), {"n": 1} if verb == "step" else None)
            assert refused["ok"] is False and f"{WORLD}/world/{verb}" in refused["error"], refused
        (mixed,) = advance(op_a, Keys(A).world_advance, {A: 0.6, B: 1.2})
        assert mixed["ok"] is False and "nothing was applied" in mixed["error"] and f"'{B}'" in mixed["error"], mixed
        assert mixed["sim_time_s"] == first[0]["sim_time_s"], "a refused advance moved time"
        wildcard = advance(op_a, "zensim/*/world/advance", {B: 1.2})
        assert not any(reply.get("ok") for reply in wildcard), wildcard
        a_status.wait(lambda s: s.rejected_requests >= rejected_before + 4, what="op-a's refusals counted in a's status")

        # op-a drives its own robot through a's key: the world advances, a's elbow follows, only a's states back.
        for _ in range(25):
            (moved,) = advance(op_a, Keys(A).world_advance, {A: 0.6})
            assert moved["ok"] and list(moved["states"]) == [A], moved
        assert moved["states"][A]["joints"]["q"][elbow] == pytest.approx(0.6, abs=0.05)
        b_after = b_joints.wait(lambda m: m.sim_time_s >= moved["sim_time_s"], what="b's state after a's advances")
        assert b_after.q[elbow] == pytest.approx(b_before, abs=1e-3), "b's elbow moved while only op-a drove"
        assert not b_status.value.paused and b_status.value.resets == 0

        # op-b: the same both ways round.
        (mixed,) = advance(op_b, Keys(B).world_advance, {A: -0.3})
        assert mixed["ok"] is False and "nothing was applied" in mixed["error"], mixed
        b_status.wait(lambda s: s.rejected_requests >= 1, what="op-b's refusal counted in b's status")
        for _ in range(25):
            (moved,) = advance(op_b, Keys(B).world_advance, {B: -0.3})
            assert moved["ok"] and list(moved["states"]) == [B], moved
        assert moved["states"][B]["joints"]["q"][elbow] == pytest.approx(-0.3, abs=0.05)

        # The unscoped operator: the whole world's key, every robot's command, and the world's verbs.
        for _ in range(25):
            (both,) = advance(operator, Keys(WORLD).world_advance, {A: 0.0, B: 0.9})
            assert both["ok"] and sorted(both["states"]) == [A, B], both
        assert both["states"][B]["joints"]["q"][elbow] == pytest.approx(0.9, abs=0.05)
        assert both["states"][A]["joints"]["q"][elbow] == pytest.approx(0.0, abs=0.05)
        (paused,) = ask(operator, f"{Keys(WORLD).root}/world/pause")
        assert paused["ok"] and paused["paused"], paused
        b_status.wait(lambda s: s.paused, what="the world paused by the unscoped operator")
    assert sim.alive(), sim.log()
