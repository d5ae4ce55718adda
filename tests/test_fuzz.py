"""Fuzz: a seeded corpus of bad input on every input key and every ctl verb, against real processes.

Router, sim (floating G1, standing) and bridge run as users run them. While the bridge keeps
commanding a good target, every kind of bad payload goes to cmd/motors, cmd/joints,
cmd/joint/{joint} and each ctl verb, plus wildcard queries. Asserted: the services stay up, every
bad sample is counted (the sim's `rejected_commands`, the bridge's `rejected_total`), every query
gets exactly one reply and it says no, the good command is still applied, the watchdog never
engages, the robot keeps standing, and the sim's memory stays bounded.

The corpus is built so that nothing in it is valid (an empty payload is a valid "all defaults"
request, so none is sent); the seed makes a failure reproducible: ZENSIM_FUZZ_SEED=<n>.
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from pathlib import Path
from typing import Any

import msgspec

from support import Latest, wait_for
from test_hostile_clients import decode_reply, no_traceback
from test_sim_process import put_json, wait_alive
from zensim.schemas import BridgeReport, JointState, Keys, Odometry, SimStatus

SEED = int(os.environ.get("ZENSIM_FUZZ_SEED", "9"))
PER_CATEGORY = 12
"""Payloads per category and key: enough to vary, few enough to stay well inside a minute."""
PACE_S = 0.002
"""Gap between bad samples: the corpus must arrive whole to be counted whole (not a flood test)."""
ELBOW = "left_elbow_joint"
GOOD_TARGET = 0.6


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


class Corpus:
    """Bad payloads by category; every one invalid for the key it is meant for."""

    def __init__(self, rng: random.Random, joints: list[str]) -> None:
        self.rng = rng
        self.joints = joints

    def _name(self) -> str:
        return self.rng.choice(self.joints)

    def structural(self, valid: dict) -> list[bytes]:
        """Malformed, oversize, nested, invalid UTF-8 and wrong-type payloads, from a valid message's shape."""
        rng, out = self.rng, []
        text = json.dumps(valid).encode()
        for _ in range(PER_CATEGORY):
            out.append(text[: rng.randrange(1, max(2, len(text) - 1))])  # truncated JSON
            out.append(b"\xc1" + bytes(rng.randrange(256) for _ in range(rng.randrange(0, 80))))  # never valid msgpack
            depth = rng.randrange(500, 4000)
            out.append(b'{"q": [0.1], "x": ' + b"[" * depth + b"]" * depth + b"}")  # deep nesting
            bad = b'"\xff\xfe' + bytes([rng.randrange(128, 256)]) + b'"'
            if "names" in valid:  # in a string the message reads (an unknown field is skipped unread)
                out.append(json.dumps({**valid, "names": ["@"]}).encode().replace(b'"@"', bad))
            else:  # requests refuse unknown fields, so this one is refused whatever its bytes
                out.append(text[:-1] + (b", " if len(valid) else b"") + b'"zz": ' + bad + b"}")
            out.append(json.dumps({**valid, "names": ["n" * rng.randrange(25_000, 60_000)]}).encode())  # oversize
            field = rng.choice(sorted(valid) or ["q"])
            out.append(json.dumps({**valid, field: rng.choice(["x", {"a": 1}, [[1]], True, [None], -1.5e9])}).encode())
        return out

    def motor_values(self) -> list[bytes]:
        """Well-formed MotorCommands a robot cannot take: out of bounds, unknown, inconsistent."""
        rng, out = self.rng, []
        for _ in range(PER_CATEGORY):
            j = self._name()
            out.append(msgspec.msgpack.encode({"names": [j], "q": [math.nan]}))
            out.append(json.dumps({"names": [j], "q": [0.1], "tau": [rng.uniform(1e4, 1e12)]}).encode())
            out.append(json.dumps({"names": [j], "q": [0.1], "dq": [rng.uniform(1e4, 1e300)], "kd": [500]}).encode())
            out.append(json.dumps({"names": [j], "q": [rng.uniform(20, 1e300) * rng.choice([-1, 1])]}).encode())
            out.append(json.dumps({"names": [j], "q": [0.1], "kp": [rng.uniform(1e6, 1e12)]}).encode())
            out.append(json.dumps({"names": [j, j], "q": [0.1, 0.2]}).encode())
            out.append(json.dumps({"names": [f"{j}_x{rng.randrange(99)}"], "q": [0.1]}).encode())
            out.append(json.dumps({"q": [0.1] * rng.choice([1, 28, 30])}).encode())
        return out

    def target_values(self) -> list[bytes]:
        rng, out = self.rng, []
        for _ in range(PER_CATEGORY):
            j = self._name()
            out.append(msgspec.msgpack.encode({"names": [j], "q": [math.inf]}))
            out.append(json.dumps({"names": [j, j], "q": [0.1, 0.2]}).encode())
            out.append(json.dumps({"names": [j], "q": [0.1, 0.2]}).encode())
            out.append(json.dumps({"names": [f"no_such_{rng.randrange(999)}"], "q": [0.1]}).encode())
        return out

    def scalars(self) -> list[bytes]:
        rng = self.rng
        return [rng.choice([b"abc", b"nan", b"inf", b"-inf", b"1e400", b"[1]", b"{}", b"\xc1\x00", b" ", b"1 2",
                            b"0x10", b'"0.5"', b"9" * 400]) for _ in range(PER_CATEGORY * 2)]

    def requests(self, verb: str) -> list[bytes]:
        valid_by_verb: dict[str, dict[str, Any]] = {"reset": {"names": [self.joints[0]], "q": [0.1], "base_height_m": 0.8},
                                                    "step": {"n": 1}, "mode": {"mode": "floating"}}
        valid = valid_by_verb.get(verb, {})
        out = self.structural(valid)
        rng = self.rng
        for _ in range(PER_CATEGORY):
            out.append(json.dumps({**valid, f"typo{rng.randrange(99)}": 1}).encode())  # unknown field
        if verb == "reset":
            out += [json.dumps({"base_height_m": h}).encode() for h in (1e300, -10.0, 1e6, 0.0, 50.0)]
            out += [json.dumps({"names": [self._name()], "q": [q]}).encode() for q in (1e6, -40.0)]
        if verb == "step":
            out += [json.dumps({"n": n}).encode() for n in (0, -1, 10**9, 1.5)]
        if verb == "mode":
            out += [json.dumps({"mode": m}).encode() for m in ("flying", "", None, 3)]
        return out



def test_fuzz_every_input_key_and_ctl_verb(start_service, zsession, robot_id):
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    reports = Latest(zsession, keys.bridge_report, BridgeReport)
    joints = Latest(zsession, keys.joints, JointState)
    odom = Latest(zsession, keys.odom, Odometry)
    watchdog_seen: list[bool] = []
    watch = zsession.declare_subscriber(keys.sim_status, lambda s: watchdog_seen.append(
        msgspec.msgpack.decode(s.payload.to_bytes())["watchdog"]))
    sim = start_service("sim")
    wait_alive(zsession, keys)
    bridge = start_service("bridge")
    wait_alive(zsession, keys, "bridge")
    info = json.loads(next(iter(zsession.get(keys.robot_info + "?format=json", timeout=5.0))).ok.payload.to_bytes())
    names = list(info["joint_names"])
    elbow = names.index(ELBOW)
    put_json(zsession, keys.joint_targets, {"names": [ELBOW], "q": [GOOD_TARGET]})
    joints.wait(lambda m: abs(m.q[elbow] - GOOD_TARGET) < 0.05, timeout_s=20, what="the good target reached")
    odom.wait(what="odometry")
    base = status.wait(lambda m: not m.watchdog, what="the bridge's commands arriving")
    reports_before = reports.value.rejected_total if reports.value else 0
    rss_before = rss_mb(sim.proc.pid)
    watchdog_seen.clear()

    corpus = Corpus(random.Random(SEED), names)
    plan = [(keys.motors, p) for p in corpus.structural({"names": [ELBOW], "q": [0.1]}) + corpus.motor_values()]
    bridge_plan = [(keys.joint_targets, p) for p in corpus.structural({"names": [ELBOW], "q": [0.1]}) + corpus.target_values()]
    bridge_plan += [(keys.joint_target(corpus.rng.choice(names)), p) for p in corpus.scalars()]
    bridge_plan += [(keys.joint_target("no_such_joint"), b"0.1")]
    samples = plan + bridge_plan
    random.Random(SEED).shuffle(samples)
    # Twice: the first pass warms up what any input would (allocator arenas, zenoh buffers); memory
    # that keeps growing in the second pass is what bad input retains.
    rss_after_pass = []
    for _ in range(2):
        for key, payload in samples:
            zsession.put(key, payload)
            time.sleep(PACE_S)
        rss_after_pass.append(rss_mb(sim.proc.pid))
    plan, bridge_plan = plan * 2, bridge_plan * 2

    queries = [(keys.ctl(verb), p) for verb in ("reset", "pause", "resume", "step", "mode") for p in corpus.requests(verb)]
    random.Random(SEED + 1).shuffle(queries)
    for key, payload in queries:
        replies = list(zsession.get(key, payload=payload, timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None, f"{key} {payload[:60]!r}: {replies}"
        answer = decode_reply(replies[0].ok.payload.to_bytes())
        assert answer["ok"] is False and answer["error"], (key, payload[:80], answer)
    wildcards = [f"zensim/{robot_id}/**", f"zensim/{robot_id}/ctl/**", "zensim/*/ctl/reset", "zensim/**"]
    for selector in wildcards:
        replies = list(zsession.get(selector, timeout=5.0))
        ctl_answers = [r for r in replies if r.ok is not None and "/ctl/" in str(r.ok.key_expr)]
        assert ctl_answers and all(not decode_reply(r.ok.payload.to_bytes())["ok"] for r in ctl_answers), selector

    sim_bad, bridge_bad = len(plan), len(bridge_plan)

    def bad_counted(m: SimStatus) -> int:
        """Refused after decoding, or shed unread behind a newer sample of this session's (anonymous) source.

        `shed_commands` also counts a bridge command overtaken by the bridge's next one (two in one take
        of the sim's command queue, when the sim is slow on a loaded machine): at least every bad one."""
        return m.rejected_commands - base.rejected_commands + m.shed_commands - base.shed_commands
    try:
        status.wait(lambda m: bad_counted(m) >= sim_bad, timeout_s=10)
    except AssertionError:
        pass
    last_seq = status.value.seq
    counted = status.wait(lambda m: m.seq > last_seq)
    assert counted.rejected_commands - base.rejected_commands <= sim_bad <= bad_counted(counted), \
        "bad commands counted by the sim"
    try:
        wait_for(lambda: reports.value and reports.value.rejected_total - reports_before >= bridge_bad, 10, "")
    except AssertionError:
        pass
    assert reports.value.rejected_total - reports_before == bridge_bad, "bad targets counted by the bridge"
    ctl_refused = status.wait(lambda m: m.rejected_requests - base.rejected_requests >= len(queries), timeout_s=10)
    assert ctl_refused.rejected_requests - base.rejected_requests >= len(queries) + len(wildcards)
    assert not ctl_refused.paused and ctl_refused.resets == base.resets and ctl_refused.mode == "floating"

    assert sim.alive() and bridge.alive()
    assert not any(watchdog_seen), "the watchdog engaged while the bridge's commands kept coming"
    t = joints.value.sim_time_s
    after = joints.wait(lambda m: m.sim_time_s > t + 0.5, timeout_s=20, what="time running")
    assert abs(after.q[elbow] - GOOD_TARGET) < 0.05, "the good command is no longer applied"
    assert odom.value.pos[2] > 0.6, f"the robot fell ({odom.value.pos[2]:.2f} m)"
    assert counted.physics_resets == 0
    growth = rss_after_pass[1] - rss_after_pass[0]
    assert growth < 5, f"sim RSS grew {growth:.1f} MB in the second pass ({rss_before:.0f} MB before the first)"
    no_traceback(sim, bridge)
    watch.undeclare()
