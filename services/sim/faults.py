"""Faults on demand for one robot: weak, locked and limp motors, encoder offsets, sensor noise and bias,
orientation drift, state dropouts and state delay. No network.

A motor fault changes what the robot's actuators do, in the model's rows that belong to this robot:
- a weak motor (`torque_scale` s): the actuator's PD gains and ctrl are written times s (physics.py's
  `_apply`, through `scale_actuators`), and the joint's peak torque (`jnt_actfrcrange`) times s, so the
  torque is s x what the healthy motor gives, clipped at s x its peak; limp is s = 0: no torque at all
  (`qfrc_actuator` and JointState.tau are exactly 0).
- a locked joint: a damper so stiff (LOCK_DAMPING_N_M_S) that the joint stays where it is when the fault is
  set: a seized gearbox that holds whatever the load. A model figure (`dof_damping`), not a new constraint:
  nothing is recompiled, and a world's other robots are untouched.
A sensor fault changes only what is reported (`observe`, on the one state reader's path, world_states.py):
an encoder offset is added to the joint's q; Gaussian noise (drawn from the request's seed, afresh for each
state read for publishing) and a constant bias are added to the IMU's gyro and accelerometer, and noise to
every joint's q and dq. The physics is untouched: a controller sees the fault, the world does not.
Then `report` (the same path, on the robot's finished JointState and Imu of one instant):
- orientation drift: Imu.quat_wxyz is turned by rate x (t - t0) about a world axis (q_axis * q_true), t0
  the sim time the fault was set or the robot last reset (a new episode: a fresh IMU);
- state delay (LinkFaults.state_delay_steps k): the readings of the last k steps are kept (a ring of at most
  k + 1 readings, one per instant: an instant read again while paused replaces its reading) and the newest
  at or before t - k steps is reported, restamped with this instant's `seq`; until one is that old, the
  oldest kept. A reset or a new fault set starts the ring over;
- dropouts: one uniform draw per state instant outside a dropout; under `dropout_probability` a dropout
  starts there and the instant's JointState and Imu are withheld (None), and every later one less than
  `dropout_s` after it. Counted in `withheld`.
state/odom and state/contacts are the sim's ground truth (viewers, recorders, scores read them; no real robot
has them): no fault touches them, so a test can always compare what the controller got with the truth.
The link's faults (command delay, dropped commands) are kept in `state` here and done by the robot's Link
(link.py), which Simulation.faults_changed hands them to.

Determinism: the noise comes from one PCG64 generator per robot, seeded at `set`, one draw of 2 x joints + 6
standard normals (q, dq, gyro, accel) for each state read; the dropouts from another (the seed's stream
DROPOUT_STREAM), one uniform per state instant outside a dropout. Drift and delay draw nothing: they follow
sim time. Under lockstep, states are read only at advances and resets, so the same seed and the same
commands give the same states, to the bit.

Everything here is for the thread holding the engine's physics lock (docs/architecture.md, "Threads"), but
`observe` and `report`, which the state publisher thread may run (a world's states): `observe` reads one
settled `_Sensing` value, replaced whole by `request`; `report` takes the `Reporting` value the frame took
with its figures (StateReader.take, physics lock held), so a fault set or a reset after that instant does not
reach it, and keeps its ring and draws under a lock of its own.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import msgspec
import mujoco
import numpy as np

from zensim.robots.builder import Robot
from zensim.schemas import FaultsRequest, FaultsState, Imu, JointState, LinkFaults, SensorFaults, short_repr

LOCK_DAMPING_N_M_S = 1e7
"""A locked joint's damping, N m s/rad: MuJoCo integrates joint damping implicitly (the implicitfast integrator),
so a damper this stiff is stable, and a joint under a load of L N m creeps at L / 1e7 rad/s (the G1's shoulder
pushed by its own motor at 20 N m: under 1e-5 rad/s, 1e-6 rad in 2 s). Two joint limits pinned to the angle
(tried first) held the angle but chattered between the stops at up to 0.05 rad/s."""


DROPOUT_STREAM = 2
"""Mixed into the seed of the dropouts' generator, so that it is neither the sensor noise's sequence nor the
link's drops' (link.DROP_STREAM)."""
TIME_SLACK_S = 1e-9
"""Sim times this close are one instant (a sum of 2 ms steps is not exactly a multiple of 2 ms)."""


def _noisy(sensors: SensorFaults | None) -> bool:
    """Whether `sensors` adds noise or bias (`observe`'s part)."""
    return sensors is not None and any((sensors.gyro_noise_std_rad_s, sensors.accel_noise_std_m_s2,
                                        sensors.q_noise_std_rad, sensors.dq_noise_std_rad_s, any(sensors.gyro_bias_rad_s),
                                        any(sensors.accel_bias_m_s2)))


def _sensing(offset: np.ndarray, sensors: SensorFaults | None, rng: np.random.Generator) -> _Sensing:
    nu = len(offset)
    if sensors is None:
        return _Sensing(np.concatenate((offset, np.zeros(nu + 6))), None, rng)
    bias = np.concatenate((offset, np.zeros(nu), sensors.gyro_bias_rad_s, sensors.accel_bias_m_s2))
    std = np.repeat([sensors.q_noise_std_rad, sensors.dq_noise_std_rad_s, sensors.gyro_noise_std_rad_s,
                     sensors.accel_noise_std_m_s2], [nu, nu, 3, 3])
    return _Sensing(bias, std if std.any() else None, rng)


class FaultError(ValueError):
    """A fault request that does not fit the robot (an unknown joint)."""


@dataclass(frozen=True)
class _Sensing:
    """What `observe` adds to one robot's reported figures (q, dq, gyro, accel, end to end); replaced whole."""

    bias: np.ndarray
    """Encoder offsets, then 0 for dq, then the gyro's and the accelerometer's biases."""
    std: np.ndarray | None
    """The noise's std, laid out as `bias`; None: no noise."""
    rng: np.random.Generator


def _turned(quat_wxyz: tuple[float, ...], axis: tuple[float, float, float], angle_rad: float) -> tuple[float, ...]:
    """`quat_wxyz` turned by `angle_rad` about the unit world `axis`: q_turn * q (mju_axisAngle2Quat and
    mju_mulQuat's figures, in plain floats: on one quaternion, numpy's calls cost more than the products)."""
    half = 0.5 * angle_rad
    c, s = math.cos(half), math.sin(half)
    x, y, z = s * axis[0], s * axis[1], s * axis[2]
    qw, qx, qy, qz = quat_wxyz
    return (c * qw - x * qx - y * qy - z * qz, c * qx + x * qw + y * qz - z * qy,
            c * qy - x * qz + y * qw + z * qx, c * qz + x * qy - y * qx + z * qw)


@dataclass(frozen=True)
class Reporting:
    """What `report` does to one robot's states from one instant on (drift, delay, dropouts); replaced whole at
    every set, clear and reset, so each value is one episode of them."""

    drift_rad_s: float
    drift_axis: tuple[float, float, float]
    """The unit world axis the IMU's orientation turns about."""
    since_s: float
    """Sim time the drift counts from: the fault's set, or the robot's last reset."""
    delay_s: float
    """The state delay, s (k steps x the timestep)."""
    dropout_probability: float
    dropout_s: float


class Faults:
    """The faults of one robot.

    Args:
        robot: the robot in the world's model.
        data: the world's MjData.
    """

    def __init__(self, robot: Robot, data: mujoco.MjData) -> None:
        self.state: FaultsState | None = None
        """What the last `set` asked for; None: no fault."""
        self.changes = 0
        """Requests that changed the faults (set, clear)."""
        self.scale: np.ndarray | None = None
        """Per joint, the torque factor (limp: 0); None: every motor healthy."""
        self._locked = np.zeros(0, int)
        """The locked joints' indices (canonical order)."""
        self._sensing: _Sensing | None = None
        self.reporting: Reporting | None = None
        """Drift, state delay and dropouts now (None: none); StateReader.take takes it with each frame."""
        self.withheld = 0
        """State instants withheld by dropouts, since start."""
        self._report_lock = threading.Lock()
        self._ring: deque[tuple[float, JointState, Imu]] = deque()
        """The state delay's past readings, oldest first (under `_report_lock`)."""
        self._ring_of: Reporting | None = None
        """The Reporting whose episode `_ring` and the dropout now belong to."""
        self._dropout_until_s: float | None = None
        """The end of the dropout under way (sim time); None: none."""
        self._dropout_rng = np.random.Generator(np.random.PCG64())
        self.attach(robot, data)

    def attach(self, robot: Robot, data: mujoco.MjData) -> None:
        """Act on `robot` in `data` from now on (at start and after a rebuild): the faults stay, in the new model."""
        self.robot, self.data = robot, data
        model = robot.model
        self._index = {name: i for i, name in enumerate(robot.joint_names)}
        self._joint_ids = model.actuator_trnid[robot.actuator_ids, 0].copy()
        """Each joint's id in the model, canonical order."""
        ids = self._joint_ids
        self._healthy = (model.jnt_actfrcrange[ids].copy(), model.dof_damping[robot.dof_adr].copy())
        """The joints' figures as built, put back when a fault ends."""
        self._write_model()

    def limits_changed(self) -> None:
        """(physics lock held) The joints' torque limits in the model were written anew (a reset drew a
        variant, variants.py, or went back to nominal): they are the healthy ones now; the faults scale them."""
        model = self.robot.model
        self._healthy = (model.jnt_actfrcrange[self._joint_ids].copy(), self._healthy[1])
        self._write_model()

    # --- requests (physics lock held) ------------------------------------------------------------

    def request(self, request: FaultsRequest) -> FaultsState | None:
        """Set or clear the faults (no verb: change nothing); the faults now.

        Raises:
            FaultError: a joint the robot lacks (nothing changed).
        """
        if request.verb is None:
            return self.state
        if request.verb == "clear":
            self.state, self.scale, self._locked, self._sensing = None, None, np.zeros(0, int), None
            self.reporting = None
        else:
            self.check(request)
            nu = self.robot.nu
            scale, offset, locked = np.ones(nu), np.zeros(nu), []
            for fault in request.joints:
                i = self._index[fault.joint]
                scale[i] = 0.0 if fault.limp else fault.torque_scale
                offset[i] = fault.encoder_offset_rad
                if fault.locked:
                    locked.append(i)
            self.scale = scale if (scale != 1.0).any() else None
            self._locked = np.array(sorted(locked), int)
            sensors = request.sensors if request.sensors != SensorFaults() else None
            self._sensing = None if not _noisy(sensors) and not offset.any() else _sensing(
                offset, sensors, np.random.Generator(np.random.PCG64(request.seed)))
            link = request.link if request.link != LinkFaults() else None
            self.state = FaultsState(joints=request.joints, sensors=sensors, seed=request.seed,
                                     set_at_s=float(self.data.time), link=link)
            with self._report_lock:  # the dropouts start over from the seed, like the noise
                self._dropout_rng = np.random.Generator(np.random.PCG64([request.seed, DROPOUT_STREAM]))
            self.reporting = self._reporting()
        self.changes += 1
        self._write_model()
        self._rebuild_constraints()
        return self.state

    def check(self, request: FaultsRequest) -> None:
        """Whether `request` fits the robot; nothing changes here.

        Raises:
            FaultError: a joint the robot lacks.
        """
        unknown = [fault.joint for fault in request.joints if fault.joint not in self._index]
        if unknown:
            known = ", ".join(self.robot.joint_names[:4])
            raise FaultError(f"ctl/faults: no joint {short_repr(unknown[0])} in {self.robot.name} (its joints: "
                             f"{known}, ...; info/robot lists them); nothing was changed")

    def relock(self) -> None:
        """Say where the locked joints are held now (after a reset put the robot in a new pose)."""
        if len(self._locked):
            self._write_model()

    def new_episode(self) -> None:
        """(after a reset) Start the drift, the state delay and any dropout over: a fresh IMU, and no reading of
        the last episode is reported in this one."""
        if self.reporting is not None:
            self.reporting = self._reporting()

    def _reporting(self) -> Reporting | None:
        """`report`'s figures for the faults set, from this instant on; None when it has nothing to do."""
        state = self.state
        if state is None:
            return None
        sensors = state.sensors or SensorFaults()
        delay = 0 if state.link is None else state.link.state_delay_steps
        if not (sensors.orientation_drift_rad_s or sensors.dropout_probability or delay):
            return None
        norm = math.hypot(*sensors.orientation_drift_axis)
        ax, ay, az = (value / norm for value in sensors.orientation_drift_axis)
        return Reporting(sensors.orientation_drift_rad_s, (ax, ay, az), float(self.data.time),
                         delay * float(self.robot.model.opt.timestep), sensors.dropout_probability,
                         sensors.dropout_s)

    # --- what the faults do ------------------------------------------------------------------------

    def scale_actuators(self, neg_kp: np.ndarray, neg_kd: np.ndarray,
                        ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A command as the faulty motors give it (mjdata.actuator_values' three arrays)."""
        scale = self.scale
        if scale is None:
            return neg_kp, neg_kd, ctrl
        return neg_kp * scale, neg_kd * scale, ctrl * scale

    def observe(self, q: np.ndarray, dq: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        """Add the sensor faults to one robot's reported figures of one instant, in place (any thread)."""
        sensing = self._sensing
        if sensing is None:
            return
        # One array and one draw for all four (numpy's call overhead, not the arithmetic, is the cost here).
        values = np.concatenate((q, dq, gyro, accel))
        values += sensing.bias
        if sensing.std is not None:
            values += sensing.std * sensing.rng.standard_normal(len(values))
        nu = len(q)
        q[:] = values[:nu]
        dq[:] = values[nu:2 * nu]
        gyro[:] = values[2 * nu:2 * nu + 3]
        accel[:] = values[2 * nu + 3:]

    def senses(self) -> bool:
        """Whether `observe` changes anything."""
        return self._sensing is not None

    def report(self, joints: JointState, imu: Imu, reporting: Reporting) -> tuple[JointState | None, Imu | None]:
        """The robot's JointState and Imu of one instant (`observe`'s figures) as the controller gets them under
        `reporting` (the frame's): drifted, delayed, or withheld (None, None). Any thread; instants in order."""
        with self._report_lock:
            if reporting is not self._ring_of:  # a new episode of the faults: nothing of the last one carries over
                self._ring.clear()
                self._dropout_until_s = None
                self._ring_of = reporting
            t = joints.sim_time_s
            if reporting.drift_rad_s:
                imu = msgspec.structs.replace(imu, quat_wxyz=_turned(
                    imu.quat_wxyz, reporting.drift_axis, reporting.drift_rad_s * (t - reporting.since_s)))
            if reporting.delay_s:
                ring = self._ring
                if ring and t <= ring[-1][0] + TIME_SLACK_S:  # no newer than the newest kept
                    if t < ring[-1][0] - TIME_SLACK_S:  # time went back (a world's reset): the past is gone
                        ring.clear()
                    else:  # the same instant read again (paused: states go on, time stands): kept once
                        ring.pop()
                ring.append((t, joints, imu))
                due = t - reporting.delay_s + TIME_SLACK_S
                while len(ring) > 1 and ring[1][0] <= due:
                    ring.popleft()
                _, old_joints, old_imu = ring[0]
                if old_joints is not joints:  # an older instant's figures, numbered as this publication
                    joints = msgspec.structs.replace(old_joints, seq=joints.seq)
                    imu = msgspec.structs.replace(old_imu, seq=imu.seq)
            if reporting.dropout_probability:
                until = self._dropout_until_s
                if until is not None and t < until - TIME_SLACK_S:
                    self.withheld += 1
                    return None, None
                self._dropout_until_s = None
                if self._dropout_rng.random() < reporting.dropout_probability:
                    self._dropout_until_s = t + reporting.dropout_s
                    self.withheld += 1
                    return None, None
            return joints, imu

    # --- inside ----------------------------------------------------------------------------------

    def _rebuild_constraints(self) -> None:
        """The velocity stage of this instant again, with the new damping: the next step's passive forces were
        worked out by the last step's mj_step1 (World.step), so without this a lock would let the joint go for
        one step. mj_step1 only recomputes the position and velocity stages from an unchanged state: every
        other figure stays the same."""
        mujoco.mj_step1(self.robot.model, self.data)

    def _write_model(self) -> None:
        """The model's figures of this robot's joints: healthy, then the faults (peaks scaled, locks damped)."""
        robot = self.robot
        model, ids = robot.model, self._joint_ids
        frcrange, damping = self._healthy
        model.jnt_actfrcrange[ids] = frcrange if self.scale is None else frcrange * self.scale[:, None]
        model.dof_damping[robot.dof_adr] = damping
        locked = self._locked
        if len(locked):
            model.dof_damping[robot.dof_adr[locked]] = LOCK_DAMPING_N_M_S
            q = self.data.qpos[robot.qpos_adr[locked]]
            if self.state is not None:
                self.state = msgspec.structs.replace(self.state, locked_q=tuple(q.tolist()))
