"""Randomisation at reset (ctl/reset `randomize`) in a real `zensim sim --clock lockstep` process, plain zenoh.

What a user running a controller over N variants of the robot relies on: the same seed gives the very
same run (bit-identical states after the same commands), another seed another run, a plain reset the
nominal robot again (the same run as before any variant); the reported factors lie in the ranges asked
for, and the reported mass is the one the floor carries; a bad request is refused whole and counted.
"""

from __future__ import annotations

import math

import msgspec
import pytest
import zenoh

from support import Latest, ctl
from test_lockstep_process import advance, scripted_command
from test_sim_process import robot_info, wait_alive
from zensim.schemas import Keys, SimStatus, Variant

RANGES = {"friction": [0.5, 1.5], "mass": [0.8, 1.2], "com_offset_m": 0.02, "motor_strength": [0.7, 1.0]}
G = 9.81


def run(session: zenoh.Session, keys: Keys, info: dict, reset: dict, n: int = 40) -> tuple[dict, list[float]]:
    """Reset with `reset`, then n closed-loop advances; the reset's reply and the last state's q, dq and base."""
    reply = ctl(session, keys.ctl("reset"), reset)
    assert reply["ok"] is True, reply
    q = list(info["default_q"][info["mode"]])
    last: dict = {}
    for k in range(n):
        last = advance(session, keys, scripted_command(k, info, q))
        assert last["ok"] is True, last
        q = last["joints"]["q"]
    return reply, [*q, *last["joints"]["dq"], *last["odom"]["pos"], *last["odom"]["quat_wxyz"]]


def test_same_seed_same_run_other_seed_other_run_plain_reset_nominal(start_service, zsession, robot_id) -> None:
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--clock", "lockstep")
    wait_alive(zsession, keys)
    info = robot_info(zsession, keys)
    assert info["variant"] is None

    nominal_reply, nominal = run(zsession, keys, info, {})
    assert nominal_reply["variant"] is None
    first_reply, first = run(zsession, keys, info, {"randomize": {"seed": 1, **RANGES}})
    again_reply, again = run(zsession, keys, info, {"randomize": {"seed": 1, **RANGES}})
    other_reply, other = run(zsession, keys, info, {"randomize": {"seed": 2, **RANGES}})

    assert again == first, "the same seed and commands must give bit-identical states"
    assert again_reply["variant"] == first_reply["variant"]
    assert other != first and other_reply["variant"] != first_reply["variant"]
    assert first != nominal

    # The factors lie within the ranges, one per link (mass, centre of mass) and joint (strength).
    for reply in (first_reply, other_reply):
        variant = reply["variant"]
        assert variant["friction_range"] == RANGES["friction"] and variant["mass_range"] == RANGES["mass"]
        assert 0.5 <= variant["friction_scale"] <= 1.5
        assert len(variant["mass_scale"]) == len(variant["bodies"]) == len(variant["com_offset_m"]) > 20
        assert all(0.8 <= f <= 1.2 for f in variant["mass_scale"])
        assert all(abs(c) <= 0.02 for offset in variant["com_offset_m"] for c in offset)
        assert len(variant["motor_strength"]) == len(info["joint_names"])
        assert all(0.7 <= f <= 1.0 for f in variant["motor_strength"])
        assert len(set(variant["mass_scale"])) == len(variant["mass_scale"]), "each link draws its own factor"
        assert 0.8 * variant["nominal_mass_kg"] <= variant["mass_kg"] <= 1.2 * variant["nominal_mass_kg"]
        assert variant["mass_kg"] != variant["nominal_mass_kg"]

    # The variant in use is reported where recordings carry it: state/sim and info/robot.
    seen = status.wait(lambda s: s.variant is not None and s.variant.seed == 2, what="state/sim with variant 2")
    assert seen.variant == msgspec.convert(other_reply["variant"], Variant)
    assert robot_info(zsession, keys)["variant"] == other_reply["variant"]

    # A plain reset is the nominal robot again: the very run it gave before any variant.
    back_reply, back = run(zsession, keys, info, {})
    assert back_reply["variant"] is None and back == nominal
    status.wait(lambda s: s.variant is None and s.resets >= 5, what="state/sim back to nominal")
    assert robot_info(zsession, keys)["variant"] is None


def standing_load_n(session: zenoh.Session, keys: Keys, info: dict, reset: dict) -> tuple[dict, float]:
    """Reset, hold the default pose 2 s, and read what the floor carries (the feet's normal forces)."""
    reply = ctl(session, keys.ctl("reset"), reset)
    assert reply["ok"] is True, reply
    hold = {"q": list(info["default_q"][info["mode"]])}
    loads = []
    for k in range(100):  # 100 advances of 10 steps: 2 s
        state = advance(session, keys, hold)
        if k >= 75:
            assert state["contacts"]["in_contact"] == [True, True], state["contacts"]
            loads.append(sum(state["contacts"]["normal_force_n"]))
    return reply, sum(loads) / len(loads)


def test_the_floor_carries_the_variants_mass(start_service, zsession, robot_id) -> None:
    keys = Keys(robot_id)
    start_service("sim", "--clock", "lockstep")
    wait_alive(zsession, keys)
    info = robot_info(zsession, keys)
    _, nominal_load = standing_load_n(zsession, keys, info, {})
    reply, heavy_load = standing_load_n(zsession, keys, info, {"randomize": {"seed": 5, "mass": [1.25, 1.25],
                                                                               "com_offset_m": 0.005}})
    variant = reply["variant"]
    assert variant["mass_kg"] == pytest.approx(1.25 * variant["nominal_mass_kg"], rel=1e-9)
    assert nominal_load == pytest.approx(variant["nominal_mass_kg"] * G, rel=0.05)
    assert heavy_load == pytest.approx(variant["mass_kg"] * G, rel=0.05)
    assert heavy_load > 1.15 * nominal_load


def test_bad_randomize_requests_are_refused_whole_and_counted(start_service, zsession, robot_id) -> None:
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--clock", "lockstep")
    wait_alive(zsession, keys)
    good = ctl(zsession, keys.ctl("reset"), {"randomize": {"seed": 3, **RANGES}})
    assert good["ok"] is True
    episode = good["episode"]
    bad = [
        {"seed": 1, "mass": [-1.0, 1.0]},          # a negative mass
        {"seed": 1, "mass": [1.2, 0.8]},           # lo above hi
        {"seed": 1, "friction": [1.0, 1e6]},       # absurd
        {"seed": 1, "motor_strength": [0.0, 1.0]},  # a limp motor is a fault, not a variant
        {"seed": 1, "com_offset_m": 5.0},          # 5 m
        {"seed": -1},                              # not a seed
        {"seed": 1, "mass": [1.0]},                # not a range
        {"seed": 1, "masses": [0.9, 1.1]},         # a typo
        {"mass": [0.9, 1.1]},                      # no seed
    ]
    for randomize in bad:
        reply = ctl(zsession, keys.ctl("reset"), {"randomize": randomize})
        assert reply["ok"] is False, randomize
        assert "\n" not in reply["error"] and len(reply["error"]) <= 240, reply["error"]
        assert reply["episode"] == episode, "nothing was reset"
    # NaN travels only in msgpack (JSON has none).
    payload = msgspec.msgpack.encode({"randomize": {"seed": 1, "mass": [math.nan, 1.0]}})
    replies = list(zsession.get(keys.ctl("reset"), payload=payload, encoding=zenoh.Encoding("application/msgpack"),
                                timeout=10.0))
    nan_reply = msgspec.msgpack.decode(replies[0].ok.payload.to_bytes())
    assert nan_reply["ok"] is False and "finite" in nan_reply["error"]
    # Counted, and the variant in use is still the good one (nothing half-applied).
    seen = status.wait(lambda s: s.rejected_requests >= len(bad) + 1, what="the refusals counted")
    assert seen.rejected_requests == len(bad) + 1 and seen.episode == episode
    assert seen.variant is not None and seen.variant == msgspec.convert(good["variant"], Variant)
