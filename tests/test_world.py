"""A world of several robots in one MuJoCo model (services/sim/world.py, robots/builder.py build_world), no network."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from support import TWO_JOINT_ARM
from zensim.common.session import StartupError
from zensim.schemas import FaultsRequest, LinkFaults, MotorCommand, SensorFaults
from zensim.sim.mjdata import read_base, read_imu
from zensim.sim.service import load_world
from zensim.sim.settings import SimSettings
from zensim.sim.world import World
from zensim.sim.world_states import States, _turn_back
from zensim.sim.world_file import read_world_file


def make_world(tmp_path: Path, body: str) -> World:
    (tmp_path / "arm.urdf").write_text(TWO_JOINT_ARM)
    path = tmp_path / "world.toml"
    path.write_text(body)
    return load_world(SimSettings(world=str(path)))[0]


def states(world: World, robot: str) -> States:
    """One robot's states now, as the sim reads them (the world's one reader)."""
    return world.reader.read(world.data, [0] * len(world))[list(world.sims).index(robot)]


def pos(world: World, robot: str) -> list[float]:
    return list(states(world, robot)[1].pos)


THREE = """
[[robots]]
id = "a"
[[robots]]
id = "b"
xy = [1.0, 0.0]
yaw_deg = 180
[[robots]]
id = "arm"
urdf = "arm.urdf"
mode = "fixed"
xy = [0.0, 3.0]
"""


def hold(world: World, robot: str, changes: dict[str, float] | None = None) -> None:
    sim = world.sims[robot]
    sim.watchdog_timeout_s = 1e6
    q = sim.robot.default_q.copy()
    for name, value in (changes or {}).items():
        q[sim.robot.joint_names.index(name)] = value
    sim.accept_command(MotorCommand(q=q.tolist()))


def test_robots_spawn_where_the_file_says_and_stand_alone_as_a_robot_alone(tmp_path: Path) -> None:
    world = make_world(tmp_path, THREE)
    a, b, arm = world.sims["a"], world.sims["b"], world.sims["arm"]
    assert np.allclose(pos(world, "b")[:2], [1.0, 0.0]) and np.allclose(pos(world, "arm")[:2], [0.0, 3.0])
    assert states(world, "b")[1].quat_wxyz[3] == pytest.approx(1.0)  # facing -x
    assert (a.mode, arm.mode) == ("floating", "fixed")
    hold(world, "a")
    hold(world, "b")
    world.step(1000)
    for name, sim in (("a", a), ("b", b)):
        assert pos(world, name)[2] > 0.65 and not sim.fallen()
    assert world.data.time == pytest.approx(2.0)


def test_one_reader_for_all_robots_says_what_each_robot_says(tmp_path: Path) -> None:
    world = make_world(tmp_path, THREE)
    hold(world, "a", {"left_elbow_joint": 1.0})
    world.step(300)
    data = world.data
    for (joints, odom, imu, _contacts), sim in zip(world.reader.read(data, [7, 8, 9]), world.sims.values()):
        robot = sim.robot
        assert joints.seq == 7 + list(world.sims.values()).index(sim) and joints.sim_time_s == data.time
        assert joints.q == data.qpos[robot.qpos_adr].tolist() and joints.dq == data.qvel[robot.dof_adr].tolist()
        assert joints.tau == data.qfrc_actuator[robot.dof_adr].tolist()
        base_pos, quat, lin_vel, ang_vel = read_base(robot, data)
        assert odom.pos == base_pos.tolist() and odom.quat_wxyz == quat.tolist()
        assert odom.lin_vel_world == lin_vel.tolist()
        assert np.allclose(odom.ang_vel_body, ang_vel, atol=1e-12)
        imu_quat, gyro, accel = read_imu(robot, data)
        assert (imu.quat_wxyz, imu.gyro, imu.accel) == (imu_quat.tolist(), gyro.tolist(), accel.tolist())


def test_robots_collide_and_a_reset_of_one_leaves_the_others_bit_identical(tmp_path: Path) -> None:
    world = make_world(tmp_path, THREE)
    a, b = world.sims["a"], world.sims["b"]
    hold(world, "a")
    hold(world, "b", {"left_shoulder_pitch_joint": -1.5, "right_shoulder_pitch_joint": -1.5,
                      "left_elbow_joint": 0.0, "right_elbow_joint": 0.0, "waist_pitch_joint": 0.5})
    touching = 0
    for _ in range(1500):
        world.step(1)
        bodies = world.model.geom_bodyid
        for contact in world.data.contact[:world.data.ncon]:
            one, two = bodies[contact.geom1], bodies[contact.geom2]
            touching += bool(one and two and (one < b.robot.slot.bodies.start) != (two < b.robot.slot.bodies.start))
    assert touching > 0
    assert a.fallen() and pos(world, "a")[0] < -0.2  # pushed over backwards by b
    before = {name: states(world, name) for name in world.sims if name != "b"}
    t = world.data.time
    b.reset()
    assert world.data.time == t
    assert pos(world, "b") == pytest.approx([1.0, 0.0, b.robot.base_height_m])
    for name, (joints, odom, _imu, contacts) in before.items():
        now = states(world, name)
        # The others' contact forces too: they are the step's, and b's reset ran its own mj_forward.
        assert now.joints == joints and now.odom == odom and now.contacts == contacts


def test_bad_world_files_are_refused_with_the_reason(tmp_path: Path) -> None:
    cases = {
        'id = "w"\nrobots = []\n': "length",
        '[[robots]]\nid = "a"\n[[robots]]\nid = "a"\n': "unique",
        '[[robots]]\nid = "A b"\n': "must match",
        '[[robots]]\nid = "a"\nxy = [1e9, 0]\n': "within 10 km",
        '[[robots]]\nid = "a"\nwheels = 4\n': "unknown field",
        '[[robots]\n': "Expected",
    }
    for text, reason in cases.items():
        path = tmp_path / "w.toml"
        path.write_text(text)
        with pytest.raises(StartupError, match=reason):
            read_world_file(str(path))


def test_held_targets_step_the_world_to_the_bit_as_step_by_step(tmp_path: Path) -> None:
    """world/advance steps with held targets (MuJoCo runs the middle steps in one call): the same states,
    to the bit, as one step at a time, with robots in contact and commands changing between advances."""
    worlds = [make_world(tmp_path, THREE) for _ in range(2)]
    for advance in range(30):
        for world in worlds:
            hold(world, "a", {"left_elbow_joint": 0.1 * advance, "waist_pitch_joint": 0.5})
            hold(world, "b", {"left_shoulder_pitch_joint": -0.05 * advance, "waist_pitch_joint": 0.5})
        worlds[0].step(10, held=True)
        worlds[1].step(10)
    one, two = (w.data for w in worlds)
    assert one.ncon > 0 and one.time == two.time
    for field in ("qpos", "qvel", "qacc", "sensordata", "qfrc_actuator"):
        assert np.array_equal(getattr(one, field), getattr(two, field)), field


def test_sensors_only_at_published_steps_give_the_same_physics_and_states_to_the_bit(tmp_path: Path) -> None:
    """The real-time loop computes MuJoCo's sensors only for the steps whose states it publishes (every 5th):
    the physics and those states are the same, to the bit, as with the sensors at every step; a read between
    (a status's fall check) gets the base's pose of its own instant, not of the last sensed step."""
    sensed, sparse = (make_world(tmp_path, THREE) for _ in range(2))
    for step in range(200):
        for world in (sensed, sparse):
            hold(world, "a", {"left_elbow_joint": 0.01 * step, "waist_pitch_joint": 0.5})
        sensed.step(1)
        sparse.step(1, sensed=(step + 1) % 5 == 0)
        if (step + 1) % 5 == 0:
            assert np.array_equal(sensed.data.sensordata, sparse.data.sensordata), step
            assert states(sensed, "a") == states(sparse, "a") and states(sensed, "b") == states(sparse, "b")
    assert sensed.data.ncon > 0
    for field in ("qpos", "qvel", "qacc", "qfrc_actuator"):
        assert np.array_equal(getattr(sensed.data, field), getattr(sparse.data, field)), field
    hold(sensed, "a", {"left_elbow_joint": 1.5})
    hold(sparse, "a", {"left_elbow_joint": 1.5})
    sensed.step(3)
    sparse.step(3, sensed=False)
    read = sparse.reader.messages(sparse.take([0] * len(sparse)))[0]  # the engine's read (World.take)
    assert read.odom == states(sensed, "a").odom, "the base's pose and twist of the instant read"
    assert read.imu.quat_wxyz == states(sensed, "a").imu.quat_wxyz and read.imu.gyro == states(sensed, "a").imu.gyro


def test_a_delayed_command_lands_mid_advance_at_its_step_to_the_bit(tmp_path: Path) -> None:
    """A command delay of 3 steps (ctl/faults' link) on robot a, advances of 10 held steps: each command lands
    at step 3 of its advance, exactly as if it had been sent then (the held steps then run one at a time);
    robot b, without the fault, is untouched by it."""
    delayed, sent_late = (make_world(tmp_path, THREE) for _ in range(2))
    sim = delayed.sims["a"]
    sim.faults.request(FaultsRequest(verb="set", link=LinkFaults(command_delay_steps=3)))
    sim.faults_changed()
    for advance in range(20):
        a_changes = {"left_elbow_joint": 0.1 * advance, "waist_pitch_joint": 0.4}
        b_changes = {"left_shoulder_pitch_joint": -0.05 * advance}
        hold(delayed, "a", a_changes)
        hold(delayed, "b", b_changes)
        delayed.step(10, held=True)
        hold(sent_late, "b", b_changes)
        sent_late.step(3)
        hold(sent_late, "a", a_changes)
        sent_late.step(7)
    one, two = delayed.data, sent_late.data
    assert one.time == two.time
    for field in ("qpos", "qvel", "qacc", "qfrc_actuator"):
        assert np.array_equal(getattr(one, field), getattr(two, field)), field


def test_drift_delay_and_dropouts_act_on_their_own_robot_and_a_delay_keeps_one_reading_per_instant(
        tmp_path: Path) -> None:
    """Robot a in a dropout that never ends, b with a state delay of 3 steps, the arm without a fault, in one
    world read by its one reader: each fault stays with its robot; states read again and again at one instant
    (a paused sim publishes on) keep one reading of it; a reset's states (`only`) touch no other robot's."""
    world = make_world(tmp_path, THREE)
    a, b, arm = (world.sims[name] for name in ("a", "b", "arm"))
    a.faults.request(FaultsRequest(verb="set", sensors=SensorFaults(dropout_probability=1.0)))
    b.faults.request(FaultsRequest(verb="set", link=LinkFaults(state_delay_steps=3)))
    start = world.sim_time_s
    for _ in range(100):
        states = world.reader.read(world.data, [1, 1, 1])
    assert len(b.faults._ring) == 1, "one instant, one reading"
    assert a.faults.withheld == 100
    times = []
    for _ in range(6):
        world.step(1)
        st_a, st_b, st_arm = world.reader.read(world.data, [2, 2, 2])
        assert st_a.joints is None and st_a.imu is None and st_a.odom.sim_time_s == world.sim_time_s
        assert st_arm.joints is not None and st_arm.joints.sim_time_s == world.sim_time_s
        assert st_b.joints is not None and st_b.imu is not None and st_b.odom.sim_time_s == world.sim_time_s
        times.append(st_b.joints.sim_time_s)
    dt = world.timestep_s
    assert times == pytest.approx([start, start, start, start + dt, start + 2 * dt, start + 3 * dt], abs=1e-12)
    assert len(b.faults._ring) == 4, "k + 1 readings at most"
    withheld, ring = a.faults.withheld, list(b.faults._ring)
    only_arm = world.reader.messages(world.take([3, 3, 3]), only=2)
    assert only_arm[0].joints is not None, "a reset's states of another robot: a's dropout draws nothing"
    assert a.faults.withheld == withheld and list(b.faults._ring) == ring
    assert states[2].joints is not None


def test_the_body_frame_turn_in_plain_floats_is_mujocos_to_the_bit() -> None:
    """A robot alone's angular velocity is turned into the body frame in plain floats (world_states._turn_back):
    the very figures MuJoCo's mju_rotVecQuat gives, for any orientation and size (and the zero vector)."""
    rng = np.random.default_rng(7)
    for scale in (0.0, 1e-6, 1.0, 50.0):
        for _ in range(2000):
            quat = rng.normal(size=4)
            quat /= np.linalg.norm(quat)
            vec = rng.normal(size=3) * scale
            out = np.zeros(3)
            mujoco.mju_rotVecQuat(out, vec, np.array([quat[0], -quat[1], -quat[2], -quat[3]]))
            assert list(_turn_back(quat.tolist(), vec.tolist())) == out.tolist()
    assert _turn_back([1.0, 0.0, 0.0, 0.0], [0.1, 0.2, 0.3]) == (0.1, 0.2, 0.3)
