"""`zensim resim FILE`: run a recording's commands through the physics again and report how far it drifts.

No network: the physics (zensim.sim.world, a world of one) runs in this process, built from the bundled robot (or
`--urdf`/`--control`) in the recorded mode and timestep, and checked against the recorded RobotInfo.

Lockstep recordings hold `state/applied`: every command with the exact sim time it took effect and
the number of steps it ran. Re-simulation starts from the recorded state at the first command's time
(a reset state at t = 0 is recreated exactly: same pose, same zeroed solver state), applies each command
at its time for its steps, and compares joint positions, base pose and the feet's normal contact forces
(state/contacts, where recorded) with the recorded state at the end of each. Same machine and build: the
divergence is 0.

A recording is untrusted input (any client may publish on the keys a recorder records): a command's
steps must lie within what a sim accepts (1..MAX_STEPS_PER_REQUEST), states must fit the robot (vector
lengths, finite numbers), a gap between recorded states longer than that many steps is not stepped
through, and the whole run has a wall-clock budget (`--budget-s`). What is skipped is said in a note.

Real-time recordings hold only what arrived on `cmd/motors`. The sim applied each at the first physics
step after it arrived, which no recording can know; resim applies it at the last state the recorder
had seen before it, i.e. up to one state period (10 ms at 100 Hz) early, and lets the watchdog's wall
clock out. The divergence then measures how much the run depended on that timing (network, load), not
an error in the physics.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from typing import Annotated, ClassVar
from dataclasses import dataclass, field

import mujoco
import msgspec
import numpy as np

from zensim.common.settings import settings_or_exit
from zensim.robots import robot_files
from zensim.schemas import AppliedCommand, Contacts, JointState, MotorCommand, Odometry, ResetRequest
from zensim.schemas.messages import MAX_STEPS_PER_REQUEST
from zensim.sim.physics import CommandError, Limits
from zensim.sim.world import World
from zensim.sim.world_states import States

from .mcapfile import Recording, read_recording
from .replay import leading_file_argument

TIME_MATCH_S = 1e-9
"""Two sim times closer than this are the same instant (both come from the same float sums)."""


class ResimSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim resim FILE`."""

    env_prefix: ClassVar[str] = "RESIM"
    file: str = ""
    """The MCAP file to re-simulate (the first argument)."""
    robot: str = "unitree_g1"
    """Bundled robot the recording was made with; ignored when --urdf is given."""
    urdf: str | None = None
    """The URDF the recording was made with, if not a bundled robot."""
    control: str | None = None
    """Its control file (default: control.toml beside it)."""
    max_kp: Annotated[float, msgspec.Meta(gt=0, le=1e6)] = 5000.0
    """Largest accepted kp, as the recording sim had it, N m/rad."""
    max_kd: Annotated[float, msgspec.Meta(gt=0, le=1e5)] = 500.0
    """Largest accepted kd, as the recording sim had it, N m s/rad."""
    budget_s: Annotated[float, msgspec.Meta(ge=1, le=86_400)] = 600.0
    """Wall-clock seconds the re-simulation may take; past it, resim stops and says so (exit code 1)."""


class OverBudget(Exception):
    """The re-simulation ran out of its wall-clock budget."""


class Budget:
    """A wall-clock deadline, checked between commands (one command runs at most MAX_STEPS_PER_REQUEST steps)."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.deadline = time.monotonic() + seconds

    def check(self, sim_time_s: float) -> None:
        if time.monotonic() > self.deadline:
            raise OverBudget(f"stopped after the --budget-s of {self.seconds:g} s, at sim time {sim_time_s:.3f} s")


@dataclass
class Divergence:
    """The largest differences between re-simulated and recorded states."""

    joint_rad: float = 0.0
    base_pos_m: float = 0.0
    base_rot_rad: float = 0.0
    foot_force_n: float = 0.0
    """The largest difference of a foot's normal contact force (recordings that hold state/contacts)."""
    compared: int = 0
    commands: int = 0
    sim_time_s: float = 0.0
    exact_start: bool = True
    skipped: int = 0
    notes: list[str] = field(default_factory=list)

    def add(self, world: World, joints: JointState | None, odom: Odometry | None,
            contacts: Contacts | None = None) -> None:
        if joints is None and odom is None:
            return
        self.compared += 1
        now = read_states(world)
        mine, mine_odom = now.joints, now.odom
        assert mine is not None  # a resim's world has no faults: no state is withheld
        if joints is not None:
            self.joint_rad = max(self.joint_rad, float(np.max(np.abs(np.subtract(mine.q, joints.q)))))
        if odom is not None:
            self.base_pos_m = max(self.base_pos_m, float(np.max(np.abs(np.subtract(mine_odom.pos, odom.pos)))))
            self.base_rot_rad = max(self.base_rot_rad, rotation_between(mine_odom.quat_wxyz, odom.quat_wxyz))
        if contacts is not None and len(contacts.normal_force_n) == len(now.contacts.normal_force_n) > 0:
            self.foot_force_n = max(self.foot_force_n, float(np.max(np.abs(np.subtract(
                now.contacts.normal_force_n, contacts.normal_force_n)))))


def read_states(world: World) -> States:
    """The robot's states now, read as the sim reads them (the world's one state reader)."""
    return world.reader.read(world.data, [0])[0]


def rotation_between(a_wxyz: Sequence[float], b_wxyz: Sequence[float]) -> float:
    """Angle of the rotation from a to b, rad: exactly 0 for equal quaternions (acos of a dot product is not)."""
    conj, rel = np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(conj, np.asarray(a_wxyz, float))
    mujoco.mju_mulQuat(rel, conj, np.asarray(b_wxyz, float))
    return 2.0 * math.atan2(float(np.linalg.norm(rel[1:])), abs(float(rel[0])))


def _instant(t: float) -> int:
    """A sim time as a dictionary key: whole microseconds (steps are milliseconds apart)."""
    return round(t * 1e6)


def fits(n_joints: int, message: object) -> bool:
    """A recorded state the robot can take: vectors of the robot's lengths, every number finite."""
    vectors: tuple[Sequence[float], ...]
    lengths: tuple[int, ...]
    if isinstance(message, JointState):
        vectors = (message.q, message.dq)
        lengths = (n_joints, n_joints)
    elif isinstance(message, Odometry):
        vectors = (message.pos, message.quat_wxyz, message.lin_vel_world, message.ang_vel_body)
        lengths = (3, 4, 3, 3)
    elif isinstance(message, Contacts):
        vectors, lengths = (message.normal_force_n,), (len(message.links),)
    else:
        return False
    return math.isfinite(message.sim_time_s) and all(
        len(v) == n and all(math.isfinite(x) for x in v) for v, n in zip(vectors, lengths))


class StateIndex:
    """Recorded joint states and odometry by sim time, within one segment (no reset inside, see
    `one_segment`, so each instant has one state). States that do not fit the robot are left out."""

    def __init__(self, recording: Recording, n_joints: int) -> None:
        self.joints = {_instant(m.sim_time_s): m for m in recording.of("state/joints") if fits(n_joints, m)}
        self.odom = {_instant(m.sim_time_s): m for m in recording.of("state/odom") if fits(n_joints, m)}
        self.contacts = {_instant(m.sim_time_s): m for m in recording.of("state/contacts") if fits(n_joints, m)}

    def at(self, t: float) -> tuple[JointState | None, Odometry | None, Contacts | None]:
        return self.joints.get(_instant(t)), self.odom.get(_instant(t)), self.contacts.get(_instant(t))


def place(world: World, joints: JointState, odom: Odometry) -> bool:
    """Put the physics in a recorded state. Returns True when that state is exactly a reset state.

    A reset zeroes everything MuJoCo carries from step to step (solver warm start included), so a
    recorded state at t = 0 is recreated bit for bit by a reset to its pose. A state taken mid-run
    sets positions and velocities only: the warm start differs, so tiny differences follow.
    """
    (sim,) = world.robots
    sim.reset(ResetRequest(q=tuple(joints.q), base_height_m=odom.pos[2]))
    now = read_states(world)
    mine, mine_odom = now.joints, now.odom
    assert mine is not None  # a resim's world has no faults: no state is withheld
    if joints.sim_time_s == 0.0 and list(mine.q) == list(joints.q) \
            and list(mine_odom.pos) == list(odom.pos) and list(mine_odom.quat_wxyz) == list(odom.quat_wxyz):
        return True
    robot, data = sim.robot, world.data
    data.qpos[robot.qpos_adr] = joints.q
    data.qvel[robot.dof_adr] = joints.dq
    if robot.free_qpos_adr >= 0:
        a = robot.free_qpos_adr
        data.qpos[a:a + 3] = odom.pos
        data.qpos[a + 3:a + 7] = odom.quat_wxyz
        d = robot.free_dof_adr  # free joint: linear velocity in the world frame, angular in the body frame
        data.qvel[d:d + 3] = odom.lin_vel_world
        data.qvel[d + 3:d + 6] = odom.ang_vel_body
    data.time = joints.sim_time_s
    mujoco.mj_forward(robot.model, data)
    return False


def resim_lockstep(world: World, recording: Recording, applied: list[AppliedCommand], budget: Budget) -> Divergence:
    (sim,) = world.robots
    states = StateIndex(recording, sim.robot.nu)
    result = Divergence()
    synced = False
    for command in applied:
        budget.check(sim.sim_time_s)
        if not 1 <= command.steps <= MAX_STEPS_PER_REQUEST or not math.isfinite(command.sim_time_s):
            result.notes.append(f"command {command.seq} skipped: {command.steps} steps at t = {command.sim_time_s:.6g} "
                                f"is not something a sim runs (1..{MAX_STEPS_PER_REQUEST} steps)")
            result.skipped += 1
            synced = False
            continue
        if not synced or abs(sim.sim_time_s - command.sim_time_s) >= TIME_MATCH_S:
            # The start, or the recording's sim was reset (or stepped by hand) since the last command.
            joints, odom, _contacts = states.at(command.sim_time_s)
            if joints is not None and odom is not None:
                result.exact_start = place(world, joints, odom) and result.exact_start
            elif command.sim_time_s == 0.0:
                # A sim publishes its t = 0 state before anyone may listen: a recorder started after the
                # sim missed it. A command at t = 0 follows a reset; the default one is the likely one
                # (a wrong guess shows up as divergence at the very next state).
                sim.reset()
                result.notes.append("no recorded state at t = 0: started from the default reset pose")
            else:
                result.skipped += 1
                synced = False
                continue
            synced = True
        try:
            sim.accept_command(command.command)
        except CommandError as exc:  # the recording sim refused it too (and did not step)
            result.notes.append(f"command {command.seq} refused: {exc}")
            continue
        world.step(command.steps, held=True)  # as the sim advances: the command held over its steps
        result.commands += 1
        result.sim_time_s = sim.sim_time_s
        result.add(world, *states.at(sim.sim_time_s))
    return result


def resim_realtime(world: World, recording: Recording, budget: Budget) -> Divergence:
    """Commands placed at the last recorded state before their arrival (see the module docstring)."""
    (sim,) = world.robots
    result = Divergence(exact_start=False)
    timeline: list[tuple[float, object]] = []
    last_t: float | None = None
    pending_odom: dict[float, Odometry] = {}
    pending_contacts: dict[float, Contacts] = {}
    n_joints = sim.robot.nu
    for item in recording.messages:
        if item.relative_key == "state/joints" and fits(n_joints, item.message):
            last_t = item.message.sim_time_s
            timeline.append((last_t, item.message))
        elif item.relative_key == "state/odom" and fits(n_joints, item.message):
            pending_odom[item.message.sim_time_s] = item.message
        elif item.relative_key == "state/contacts" and fits(n_joints, item.message):
            pending_contacts[item.message.sim_time_s] = item.message
        elif item.relative_key == "cmd/motors" and last_t is not None:
            timeline.append((last_t, item.message))
    states = [(t, m) for t, m in timeline if isinstance(m, JointState) and t in pending_odom]
    if not states:
        result.notes.append("no recorded states to start from")
        return result
    t0, first = states[0]
    place(world, first, pending_odom[t0])
    dt = world.timestep_s
    for t, message in timeline:
        budget.check(sim.sim_time_s)
        if t < t0:
            continue
        if isinstance(message, MotorCommand):
            try:
                sim.accept_command(message)
                result.commands += 1
            except CommandError as exc:
                result.notes.append(f"a command refused: {exc}")
            continue
        n = round((t - sim.sim_time_s) / dt)
        if n > MAX_STEPS_PER_REQUEST and t in pending_odom:
            # Longer than any sim steps between two states: a forged or damaged time. Start over there.
            result.notes.append(f"a gap of {t - sim.sim_time_s:.6g} s between recorded states was not stepped "
                                f"through: re-started from the state at t = {t:.6g} s")
            place(world, message, pending_odom[t])  # type: ignore[arg-type]
            continue
        if 0 < n <= MAX_STEPS_PER_REQUEST:
            world.step(n)
            result.sim_time_s = sim.sim_time_s
            result.add(world, message if isinstance(message, JointState) else None, pending_odom.get(t),
                       pending_contacts.get(t))
    return result


def one_segment(recording: Recording) -> tuple[str, str | None]:
    """Keep the longest stretch of the recording with no reset and no mode switch in it.

    A reset starts sim time over and a mode switch rebuilds the model: re-simulating across either
    would compare states of different runs. Returns the segment's mode and a note on what was left
    out (None when the recording is one segment).
    """
    info = recording.robot_info
    messages = recording.messages
    cuts, mode, last_t = [0], info.mode if info is not None else "floating", None
    modes = [mode]
    for i, item in enumerate(messages):
        if item.relative_key == "state/sim" and item.message.mode != modes[-1]:
            cuts.append(i)
            modes.append(item.message.mode)
            last_t = None
        elif item.relative_key == "state/joints":
            t = item.message.sim_time_s
            if last_t is not None and t < last_t - TIME_MATCH_S:
                cuts.append(i)
                modes.append(modes[-1])
            last_t = t
    cuts.append(len(messages))
    segments = list(zip(cuts, cuts[1:], modes))
    if len(segments) == 1:
        return modes[0], None

    def states(segment: tuple[int, int, str]) -> int:
        return sum(1 for m in messages[segment[0]:segment[1]] if m.relative_key == "state/joints")

    start, end, mode = max(segments, key=states)
    first = next((m.message.sim_time_s for m in messages[start:end] if m.relative_key == "state/joints"), 0.0)
    recording.messages = messages[start:end]
    return mode, (f"the recording has {len(segments)} segments (resets or mode switches); re-simulated the longest, "
                  f"{mode} mode from t = {first:.3f} s")


def build_sim(settings: ResimSettings, recording: Recording, mode: str) -> World:
    """A world of the recorded robot, as the recording sim had it (its mode, step and bounds)."""
    info = recording.robot_info
    if info is None:
        raise ValueError("the recording holds no info/robot: start `zensim record` while the sim runs")
    files = robot_files(None if settings.urdf else settings.robot, urdf=settings.urdf, control=settings.control)
    world = World.alone("resim", files, mode, Limits(max_kp=settings.max_kp, max_kd=settings.max_kd),  # type: ignore[arg-type]
                        watchdog_timeout_s=info.watchdog_timeout_s, timestep_s=info.timestep_s,
                        terrain=info.terrain)  # the recorded ground: the same run needs the same terrain
    (sim,) = world.robots
    sim.watchdog_enabled = False  # wall-clock silences are not in the recording
    if tuple(sim.robot.joint_names) != tuple(info.joint_names):
        raise ValueError(f"the recording is of {info.model} with other joints than {sim.robot.name}; "
                         "pass the recorded robot with --robot or --urdf")
    return world


def main(argv: Sequence[str] | None = None) -> int:
    args = leading_file_argument(sys.argv[1:] if argv is None else argv)
    settings = settings_or_exit(ResimSettings, args, "zensim resim")
    if not settings.file:
        print("usage: zensim resim FILE [--robot NAME | --urdf PATH]", file=sys.stderr)
        return 2
    try:
        recording = read_recording(settings.file)
        mode, cut = one_segment(recording)
        world = build_sim(settings, recording, mode)
    except (OSError, ValueError) as exc:
        print(f"zensim resim: {exc}", file=sys.stderr)
        return 2
    applied = recording.of("state/applied")
    kind = "lockstep" if applied else "real-time"
    budget = Budget(settings.budget_s)
    try:
        result = resim_lockstep(world, recording, applied, budget) if applied else resim_realtime(world, recording, budget)
    except OverBudget as exc:
        print(f"zensim resim: {exc}", file=sys.stderr)
        return 1
    (sim,) = world.robots
    print(f"resim {settings.file}: {kind} recording of {recording.robot_id} ({sim.robot.name}, {sim.mode}), "
          f"{result.commands} commands, {result.compared} states compared, up to t = {result.sim_time_s:.3f} s")
    print(f"largest divergence: joint position {result.joint_rad:.6g} rad, base position {result.base_pos_m:.6g} m, "
          f"base orientation {result.base_rot_rad:.6g} rad, foot normal force {result.foot_force_n:.6g} N")
    if kind == "lockstep":
        if result.exact_start:
            print("lockstep: every command re-applied at its recorded sim time from a reset state; on the same "
                  "machine and build this is 0 (bit-identical).")
        else:
            print("lockstep, but the recording starts mid-run: positions and velocities were restored, the "
                  "solver's warm start was not, so small differences are expected.")
    else:
        print("real-time: commands were applied at the last state recorded before they arrived (up to one state "
              "period off the step the sim used), so this measures how much the run depended on network and "
              "load timing, not an error in the physics.")
    if cut:
        print(f"note: {cut}")
    if result.skipped:
        print(f"note: {result.skipped} commands skipped: no recorded state at their start time (samples lost), "
              "or steps no sim runs")
    if recording.unreadable:
        print(f"note: {recording.unreadable} messages of the file did not decode as their key's type and were skipped")
    for note in result.notes[:10]:
        print(f"note: {note}")
    if result.compared == 0:
        print("nothing was compared: the recording holds no states after its commands", file=sys.stderr)
        return 1
    return 0
