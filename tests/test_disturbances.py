"""Pushes and the band in the physics alone (services/sim/disturbances.py through a World, no network)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from support import TWO_JOINT_ARM
from zensim.robots import robot_files
from zensim.schemas import BandRequest, MotorCommand, PushRequest
from zensim.sim.disturbances import DisturbanceError
from zensim.sim.physics import Limits
from zensim.sim.service import load_world
from zensim.sim.settings import SimSettings
from zensim.sim.world import World


def g1(mode: str = "floating") -> World:
    world = World.alone("g1", robot_files("g1"), mode, Limits(5000, 500), 1e9)  # type: ignore[arg-type]
    (sim,) = world.robots
    sim.accept_command(MotorCommand(q=sim.robot.default_q.tolist()))
    return world


def test_a_push_acts_on_whole_steps_only_on_its_body_and_leaves_nothing_behind() -> None:
    world = g1()
    (sim,) = world.robots
    disturbances, model, data = sim.disturbances, world.model, world.data
    hand = model.body("left_wrist_yaw_link").id
    state = disturbances.push(PushRequest(direction=(0, 0, 2), magnitude_n=30, duration_s=0.0071, body="left_wrist_yaw_link"))
    assert state.duration_s == pytest.approx(0.008) and state.force_n == (0.0, 0.0, 30.0)  # 3.55 steps: 4
    seen = []
    for _ in range(6):
        world.step(1)
        seen.append(data.xfrc_applied[hand, 2])
    # xfrc_applied holds what the step just run used: 4 steps of 30 N, then cleared.
    assert seen == [30.0, 30.0, 30.0, 30.0, 0.0, 0.0]
    assert not np.any(data.xfrc_applied) and not disturbances.active()
    # A push cut short by a reset: its row is cleared at once.
    disturbances.push(PushRequest(direction=(1, 0, 0), magnitude_n=30, duration_s=1.0))
    world.step(3, held=True)
    assert np.any(data.xfrc_applied)
    sim.reset()
    assert not np.any(data.xfrc_applied) and disturbances.push_states() == ()


def test_a_disturbed_advance_is_the_same_as_the_same_steps_one_by_one() -> None:
    """An advance steps one by one while a force acts (it changes at every step): to the bit, run twice."""
    runs = []
    for _ in range(2):
        world = g1()
        (sim,) = world.robots
        sim.disturbances.band(BandRequest(verb="on"))
        sim.disturbances.push(PushRequest(direction=(1, -1, 0), magnitude_n=100, duration_s=0.05))
        for _ in range(10):
            world.step(10, held=True)
        runs.append(world.data.qpos.copy())
    assert np.array_equal(runs[0], runs[1])


def test_the_band_only_pulls_and_is_refused_where_it_cannot_act() -> None:
    world = g1()
    (sim,) = world.robots
    disturbances = sim.disturbances
    # Standing on the floor under a long band: slack, no force at all.
    assert disturbances.band(BandRequest(verb="on", length_m=4.0)).on
    world.step(5)
    assert not np.any(disturbances.band_force) and not np.any(world.data.xfrc_applied)
    # Shortened to 0: it lifts the robot (the G1's feet off the floor within 2 s).
    disturbances.band(BandRequest(length_m=0.0))
    for _ in range(1000):
        world.step(1)
    assert world.data.xpos[sim.robot.base_body_id][2] > 1.0
    assert disturbances.band_force[2] > 0
    assert disturbances.band(BandRequest(verb="lower")).length_m == pytest.approx(0.1)
    assert disturbances.band(BandRequest(verb="raise")).length_m == 0.0
    with pytest.raises(DisturbanceError, match="shortest"):
        disturbances.band(BandRequest(verb="raise"))
    disturbances.band(BandRequest(verb="off"))
    world.step(1)
    assert not np.any(world.data.xfrc_applied) and not disturbances.active()
    fixed = g1("fixed").robots[0].disturbances
    with pytest.raises(DisturbanceError, match="fixed"):
        fixed.band(BandRequest(verb="on"))


def test_the_band_alone_and_with_pushes_writes_exactly_its_forces_and_follows_a_rebuild() -> None:
    """The band alone takes a short way (its row written in place): it must write what the general way does
    while pushes start and end beside it, on its own row and another, and act on a rebuilt robot's new data."""
    world = g1()
    (sim,) = world.robots
    disturbances, data = sim.disturbances, world.data
    base, hand = sim.robot.base_body_id, world.model.body("left_wrist_yaw_link").id
    disturbances.band(BandRequest(verb="on", length_m=0.5))  # taut: a pull of some 300 N
    world.step(2)
    disturbances.push(PushRequest(direction=(1, 0, 0), magnitude_n=10, duration_s=0.004))  # 2 steps, on the base
    disturbances.push(PushRequest(direction=(0, 0, 1), magnitude_n=30, duration_s=0.006, body="left_wrist_yaw_link"))
    disturbances.push(PushRequest(direction=(0, 0, 1), magnitude_n=5, duration_s=0.002, body="left_wrist_yaw_link"))
    for step in range(6):
        world.step(1)
        band = np.array(disturbances.band_force)
        assert band[2] > 100
        np.testing.assert_array_equal(data.xfrc_applied[base, :3], band + ([10.0, 0, 0] if step < 2 else 0.0))
        hand_n = 35.0 if step == 0 else 30.0 if step < 3 else 0.0  # two pushes on one body add up
        np.testing.assert_array_equal(data.xfrc_applied[hand, :3], [0, 0, hand_n])
        others = np.delete(data.xfrc_applied, [base, hand], axis=0)
        assert not np.any(others) and not np.any(data.xfrc_applied[:, 3:])
    world.rebuild("floating")
    world.step(1)
    assert world.data is not data and world.data.xfrc_applied[base, 2] == disturbances.band_force[2] > 100


def test_push_refusals_name_the_bound_and_change_nothing() -> None:
    world = g1()
    disturbances = world.robots[0].disturbances
    good = {"direction": (1.0, 0.0, 0.0), "magnitude_n": 50.0, "duration_s": 0.1}
    with pytest.raises(DisturbanceError, match="no body 'tail'"):
        disturbances.push(PushRequest(**good, body="tail"))  # type: ignore[arg-type]
    with pytest.raises(DisturbanceError, match=r"10 x the robot's weight"):
        disturbances.push(PushRequest(**{**good, "magnitude_n": 1e9}))  # type: ignore[arg-type]
    for _ in range(16):
        disturbances.push(PushRequest(**good))  # type: ignore[arg-type]
    with pytest.raises(DisturbanceError, match="16 pushes"):
        disturbances.push(PushRequest(**good))  # type: ignore[arg-type]
    assert disturbances.pushes_applied == 16
    for bad in ({"magnitude_n": float("inf")}, {"direction": (float("nan"), 0.0, 0.0)}, {"duration_s": 0.0},
                {"duration_s": 10.5}, {"magnitude_n": -1.0}):
        with pytest.raises(ValueError):
            PushRequest(**{**good, **bad})  # type: ignore[arg-type]


def test_each_robot_of_a_world_is_pushed_by_its_own_link_names(tmp_path: Path) -> None:
    (tmp_path / "arm.urdf").write_text(TWO_JOINT_ARM)
    path = tmp_path / "world.toml"
    path.write_text('[[robots]]\nid = "a"\n[[robots]]\nid = "b"\nxy = [2.0, 0.0]\n')
    world = load_world(SimSettings(world=str(path)))[0]
    a, b = world.robots
    assert set(a.disturbances.bodies) == set(b.disturbances.bodies) and "pelvis" in a.disturbances.bodies
    assert a.disturbances.bodies["pelvis"] != b.disturbances.bodies["pelvis"]
    assert list(b.disturbances.anchor[:2]) == [2.0, 0.0], "the band hangs over the robot's own spawn place"
    b.disturbances.push(PushRequest(direction=(0, 1, 0), magnitude_n=40, duration_s=0.01))
    world.step(1)
    assert world.data.xfrc_applied[b.robot.base_body_id, 1] == 40.0
    assert not np.any(world.data.xfrc_applied[a.robot.base_body_id])
