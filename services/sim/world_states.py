"""Every robot's states of one instant in a world: read from MjData in one pass, put from a thread of their own.

The engine's loop holds the physics lock while it steps and reads (engine.py). Reading is a handful of numpy
gathers for all robots at once (`StateReader.take`: a `Frame` of plain arrays, copies, so MjData may
step on). Turning a frame into three messages per robot, encoding and putting them is Python work
that grows with the robot count (a fifth of a 32-G1 world's loop, benchmarks/world_profile.py);
`StatePublisher` does it on a thread of its own. MuJoCo releases the GIL inside mj_step, so that work
runs on the other core while the loop steps the next instant, instead of after it.

Order is kept: frames go out oldest first, and a state put by any other path (a reset, ctl/step,
world/advance) waits for the frames before it (`StatePublisher.drain`), so `seq` never goes back.

The sensor faults (faults.py) act in `messages`: noise and bias on the arrays (`observe`), then drift, state
delay and dropouts on each robot's finished JointState and Imu (`report`, with the faults' figures the frame
took at its instant). A delay hands out an older instant's messages, a dropout None for both (not put);
state/odom and state/contacts are the truth, untouched.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import mujoco
import numpy as np

from zensim.common.logs import RateLimitedLog
from zensim.robots.builder import FOOT_NET_SUFFIX, FOOT_POINTS_SUFFIX
from zensim.schemas import Contacts, Imu, JointState, Odometry

from .faults import Reporting
from .physics import Simulation

logger = logging.getLogger("zensim.sim")


class States(NamedTuple):
    """One robot's messages of one instant."""

    joints: JointState | None
    """None: withheld by a sensor dropout (ctl/faults), with `imu`; not published."""
    odom: Odometry
    imu: Imu | None
    """None: withheld by a sensor dropout, with `joints`."""
    contacts: Contacts

MAX_BACKLOG = 10
"""Frames that may wait for the publisher thread (100 ms of states at 100 Hz); past it the oldest is
dropped and counted: a late state is worth less than a current one, and memory stays bounded."""
FEW_ROBOTS = 4
"""Up to this many robots, a frame's body-frame angular velocities are turned row by row in plain floats (_turn_back)."""
DRAIN_TIMEOUT_S = 1.0
"""Longest a direct put waits for the frames before it (a put never blocks that long: zenoh drops)."""


@dataclass(frozen=True)
class Frame:
    """Every robot's measured figures of one instant, as arrays owned by nobody else (copies of MjData's)."""

    sim_time_s: float
    seqs: tuple[int, ...]
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    sensors: dict[str, np.ndarray]
    """Each sensor of StateReader.SENSORS, one row per robot."""
    feet_net: np.ndarray
    """Every robot's feet, in turn: contacts found and the net force the foot exerts (world), one row per foot."""
    feet_normal_n: np.ndarray
    """Every robot's feet, in turn: the sum of the foot's contact points' normal forces, N."""
    reports: tuple[Reporting | None, ...] = ()
    """Each robot's drift, state delay and dropouts at this instant (faults.py); empty: none has any."""

    def tilts_rad(self) -> np.ndarray:
        """Each robot's base tilt from upright, rad (as mjdata.base_tilt_rad, for all robots at once)."""
        quat = self.sensors["base_quat"]
        norm2 = np.einsum("ij,ij->i", quat, quat)
        cos_tilt = 1.0 - 2.0 * (quat[:, 1] ** 2 + quat[:, 2] ** 2) / norm2
        return np.arccos(np.clip(cos_tilt, -1.0, 1.0))


class StateReader:
    """Reads every robot's JointState, Odometry, Imu and Contacts of one instant from the world's MjData in a few
    array operations (one gather per field for all robots, then list slices), not four per robot.

    The one state reader: the sim (a robot alone is a world of one), world/advance and `zensim resim` all
    read states here. The body-frame angular velocity is the world one turned by the base's inverse
    orientation (mjdata.read_base's figure), here for all robots at once."""

    SENSORS = ("base_pos", "base_quat", "base_linvel", "base_angvel", "imu_quat", "imu_gyro", "imu_accel")

    def __init__(self, sims: Sequence[Simulation]) -> None:
        robots = [sim.robot for sim in sims]
        self.faults = [sim.faults for sim in sims]
        """Each robot's faults: their sensor part changes what `messages` reports."""
        self.qpos = np.concatenate([r.qpos_adr for r in robots])
        self.dof = np.concatenate([r.dof_adr for r in robots])
        ends = np.cumsum([r.nu for r in robots])
        self.spans = list(zip([0, *ends[:-1].tolist()], ends.tolist()))
        self.sensors = {name: np.stack([np.arange(r.sensor_slices[name].start, r.sensor_slices[name].stop)
                                        for r in robots]) for name in self.SENSORS}
        # The feet: robots have any number (an arm none), so one row per foot of every robot, and each robot's span.
        feet = [(r, link) for r in robots for link in r.foot_links]
        self.foot_links = [r.foot_links for r in robots]
        feet_ends = np.cumsum([len(r.foot_links) for r in robots])
        self.foot_spans = list(zip([0, *feet_ends[:-1].tolist()], feet_ends.tolist()))
        self.feet_net = _rows([r.sensor_slices[link + FOOT_NET_SUFFIX] for r, link in feet], 4)
        # Of each contact point's force (normal, tangent, tangent in its contact frame) only the normal is summed.
        self.feet_normals = _rows([r.sensor_slices[link + FOOT_POINTS_SUFFIX] for r, link in feet], None)[:, ::3]

    def take(self, data: mujoco.MjData, seqs: Sequence[int]) -> Frame:
        """(physics lock held) This instant's figures; fancy indexing copies, so the frame outlives the step."""
        sensordata = data.sensordata
        reports = tuple(faults.reporting for faults in self.faults)
        return Frame(float(data.time), tuple(seqs), data.qpos[self.qpos], data.qvel[self.dof],
                     data.qfrc_actuator[self.dof], {name: sensordata[idx] for name, idx in self.sensors.items()},
                     sensordata[self.feet_net], sensordata[self.feet_normals].sum(axis=1),
                     reports if any(report is not None for report in reports) else ())

    def messages(self, frame: Frame, only: int | None = None) -> list[States]:
        """Each robot's messages of a frame, in the order of the sims given (any thread). `only`: robot `only`'s
        alone are going out (a reset's): the others' sensor faults draw nothing and keep no reading of it."""
        t, s = frame.sim_time_s, frame.sensors
        q, dq, gyro_rows, accel_rows = frame.q, frame.dq, s["imu_gyro"], s["imu_accel"]
        if any(faults.senses() for faults in self.faults):  # what the faulty sensors report, not the truth
            q, dq, gyro_rows, accel_rows = q.copy(), dq.copy(), gyro_rows.copy(), accel_rows.copy()
            for i, ((a, b), faults) in enumerate(zip(self.spans, self.faults)):
                if only is None or i == only:
                    faults.observe(q[a:b], dq[a:b], gyro_rows[i], accel_rows[i])
        q, dq, tau = q.tolist(), dq.tolist(), frame.tau.tolist()
        pos, quat, lin = s["base_pos"].tolist(), s["base_quat"].tolist(), s["base_linvel"].tolist()
        if len(quat) <= FEW_ROBOTS:
            ang = [_turn_back(row, angvel) for row, angvel in zip(quat, s["base_angvel"].tolist())]
        else:
            ang = _rotate_by_inverse(s["base_quat"], s["base_angvel"]).tolist()
        imu_quat, gyro, accel = s["imu_quat"].tolist(), gyro_rows.tolist(), accel_rows.tolist()
        # The sensor gives the force the foot exerts on what it touches: the force ON the foot is its opposite.
        found = frame.feet_net[:, 0]
        points, touching = found.astype(int).tolist(), (found > 0).tolist()
        force, normal = (-frame.feet_net[:, 1:]).tolist(), frame.feet_normal_n.tolist()
        states = [States(JointState(sim_time_s=t, seq=seq, q=q[a:b], dq=dq[a:b], tau=tau[a:b]),
                         Odometry(sim_time_s=t, seq=seq, pos=pos[i], quat_wxyz=quat[i], lin_vel_world=lin[i],
                                  ang_vel_body=ang[i]),
                         Imu(sim_time_s=t, seq=seq, quat_wxyz=imu_quat[i], gyro=gyro[i], accel=accel[i]),
                         Contacts(sim_time_s=t, seq=seq, links=links, in_contact=tuple(touching[f:g]),
                                  normal_force_n=normal[f:g], force_world=tuple(force[f:g]), points=tuple(points[f:g])))
                  for i, ((a, b), (f, g), links, seq) in enumerate(zip(self.spans, self.foot_spans, self.foot_links,
                                                                      frame.seqs))]
        # Drift, state delay and dropouts: on the finished messages (a delay hands out an older instant's whole).
        for i, reporting in enumerate(frame.reports):
            if reporting is not None and (only is None or i == only):
                joints, odom, imu, contacts = states[i]
                assert joints is not None and imu is not None  # built just above
                joints, imu = self.faults[i].report(joints, imu, reporting)
                states[i] = States(joints, odom, imu, contacts)
        return states

    def read(self, data: mujoco.MjData, seqs: Sequence[int]) -> list[States]:
        """(physics lock held) take and messages in one go."""
        return self.messages(self.take(data, seqs))


def _rows(slices: list[slice], width: int | None) -> np.ndarray:
    """The sensordata indices of `slices` as one row each (all of `width`, or all of one width); (0, w) when none."""
    if not slices:
        return np.zeros((0, width or 3), int)
    return np.stack([np.arange(part.start, part.stop) for part in slices])


def _turn_back(quat_wxyz: list[float], vec: list[float]) -> tuple[float, float, float]:
    """`vec` turned by the inverse of the unit quaternion (MuJoCo's mju_rotVecQuat with the conjugate: its
    operations in its order, so the same figures to the bit; tests/test_world.py). Plain floats: a robot alone's
    one vector in 0.5 us, where MuJoCo's call on numpy arrays took 3-5 us (3 % of the loop at --rtf 0)."""
    w, x, y, z = quat_wxyz[0], -quat_wxyz[1], -quat_wxyz[2], -quat_wxyz[3]
    v0, v1, v2 = vec
    if v0 == 0 and v1 == 0 and v2 == 0:
        return (0.0, 0.0, 0.0)
    if w == 1 and x == 0 and y == 0 and z == 0:
        return (v0, v1, v2)
    t0 = w * v0 + y * v2 - z * v1
    t1 = w * v1 + z * v0 - x * v2
    t2 = w * v2 + x * v1 - y * v0
    return (v0 + 2 * (y * t2 - z * t1), v1 + 2 * (z * t0 - x * t2), v2 + 2 * (x * t1 - y * t0))


def _rotate_by_inverse(quat_wxyz: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Each row of `vec` turned by the inverse of each unit quaternion, with numpy for all rows at once (many
    robots; a few take `_turn_back` row by row)."""
    w = quat_wxyz[:, :1]
    u = -quat_wxyz[:, 1:]
    t = 2.0 * _cross(u, vec)
    return vec + w * t + _cross(u, t)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of two (n, 3) arrays: the same figures as np.cross, in a third of its time."""
    a1, a2, a3 = a[:, 0], a[:, 1], a[:, 2]
    b1, b2, b3 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack((a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1), axis=1)


class StatePublisher:
    """Puts the frames the loop hands over, oldest first, from a thread of its own (or at once).

    Args:
        reader: turns a frame into messages.
        put: puts one instant's messages of every robot (in the reader's robot order).
        threaded: put from a thread of its own (a world of several robots); False: put at once, on the
            caller's thread (a robot alone: its three messages cost less than the hand-over would add to
            a state's latency).
    """

    def __init__(self, reader: StateReader, put: Callable[[list[States]], None], threaded: bool = True) -> None:
        self.reader = reader
        self._put = put
        self._threaded = threaded
        self._frames: deque[Frame | list[States]] = deque()
        self._busy = False
        self._closed = False
        self._ready = threading.Condition()
        self.dropped = 0
        """Frames dropped unput because the thread was MAX_BACKLOG frames behind (under the condition's lock)."""
        self._drop_log = RateLimitedLog(logger)
        self._fail_log = RateLimitedLog(logger)
        self._thread = threading.Thread(target=self._run, name="sim-states", daemon=True)
        if threaded:
            self._thread.start()

    def submit(self, frame: Frame | list[States]) -> None:
        """Queue a frame, or messages already built (world/advance built them for its reply); returns at
        once. The oldest is dropped when MAX_BACKLOG wait already."""
        if not self._threaded:
            self._put(self.reader.messages(frame) if isinstance(frame, Frame) else frame)
            return
        with self._ready:
            if len(self._frames) >= MAX_BACKLOG:
                self._frames.popleft()
                self.dropped += 1
                self._drop_log.warning("a world's states dropped unput: the publisher thread is %d instants "
                                       "behind (%d dropped so far)", MAX_BACKLOG, self.dropped)
            self._frames.append(frame)
            self._ready.notify_all()

    def drain(self) -> None:
        """Wait until every frame queued so far has been put (before a state goes out by another path)."""
        if not self._threaded:
            return
        with self._ready:
            if not self._ready.wait_for(lambda: self._closed or not (self._frames or self._busy), DRAIN_TIMEOUT_S):
                logger.warning("the state publisher thread did not finish within %.1f s", DRAIN_TIMEOUT_S)

    def _run(self) -> None:
        while True:
            with self._ready:
                self._busy = False
                self._ready.notify_all()
                self._ready.wait_for(lambda: self._closed or self._frames)
                if self._closed:
                    return
                frame = self._frames.popleft()
                self._busy = True
            try:
                self._put(self.reader.messages(frame) if isinstance(frame, Frame) else frame)
            except Exception:  # a failed put must not end the states of every robot
                self._fail_log.exception("putting a world's states failed")

    def close(self) -> None:
        """Put what is queued, then end the thread."""
        if not self._threaded:
            return
        self.drain()
        with self._ready:
            self._closed = True
            self._ready.notify_all()
        self._thread.join(DRAIN_TIMEOUT_S)
