"""The G1's locomotion controller as the sim's robot runs it: an FSM, Unitree's walking policy, arm_sdk.

No DDS, no zenoh: `LocoController.tick` takes one instant of the sim (joints, IMU, sim time) and returns
the motor targets for every joint, or None when nothing is to be sent. The adapter calls it for every
sim state and publishes what it returns; everything here runs on sim time, so it behaves the same under
the realtime and the lockstep clock.

FSM ids (those of unitree_sdk2's LocoClient):

    0    zero torque      every motor kp = kd = 0: the robot collapses
    1    damp             kp = 0, kd > 0: the robot folds slowly
    3    sit              ramp to the squat, then hold it
    500  start            stand up if needed, then balance and walk (the policy) at the commanded velocity
    702  lie-to-stand     as squat-to-stand (a ramp to the stance: works from a crouch, not from lying flat)
    706  squat-to-stand   ramp through the squat to the stance (SQUAT_S + STAND_UP_S), then as start;
                          sent while standing (balancing or walking on the policy): stand-to-squat
Before the first FSM request the controller is passive (sends nothing): a low-level program on
rt/lowcmd has the robot to itself until someone asks the sport service for a mode; the motion switcher's
ReleaseMode makes it passive again. A sim reset (sim time going back) restarts the current mode from the
spawn squat (walking: it stands up first).

Walking runs the policy every CONTROL_DT_S of sim time on the 12 leg joints with its trained gains; the
waist and arms are held stiff at 0 rad (UPPER_KP/UPPER_KD), as in training, where the upper body was
welded: with softer arms the arm swing turns the robot and a straight command curves.

arm_sdk: a LowCmd_ on rt/arm_sdk carries targets for the waist and arm motors (12..28) and, in motor 29's
q, a weight w in [0, 1]; each of those motors then gets w x arm_sdk + (1 - w) x controller for q, dq,
tau, kp and kd (the legs stay with the controller). The newest arm_sdk command holds until the next.
One exception: the waist (12..14) blends its targets but keeps the controller's gains. The policy
balances the robot as if the upper body were rigid; measured in the sim, the SDK example's kp 60 on the
waist with the arms lifted lets the pelvis run forward and the robot fall within 3 s, while with the
waist stiff it stands through the whole example.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from zensim.schemas import RobotInfo

from .walk_policy import (CONTROL_DT_S, DEFAULT_LEG_Q, LEG_KD, LEG_KP, NUM_ACTIONS, WalkPolicy,
                          observation)

NUM_JOINTS: Final = 29
"""The G1 29-DoF: 0-11 legs, 12-14 waist, 15-28 arms (Unitree's motor order = the sim's joint order)."""
ARM_SDK_FIRST: Final = 12
NUM_WAIST: Final = 3
ARM_SDK_WEIGHT_SLOT: Final = 29
"""kNotUsedJoint: its q is the arm_sdk weight."""

FSM_ZERO_TORQUE: Final = 0
FSM_DAMP: Final = 1
FSM_SIT: Final = 3
FSM_START: Final = 500
FSM_LIE_TO_STAND: Final = 702
FSM_SQUAT_STAND: Final = 706
FSM_IDS: Final = (FSM_ZERO_TORQUE, FSM_DAMP, FSM_SIT, FSM_START, FSM_LIE_TO_STAND, FSM_SQUAT_STAND)

STAND_Q: Final = np.concatenate([DEFAULT_LEG_Q, np.zeros(NUM_JOINTS - NUM_ACTIONS)])
"""The policy's stance, upper body at 0."""
STAND_UP_S: Final = 1.5
"""Sim time a ramp from the squat to the stance (or from anywhere to the squat) takes."""
SQUAT_S: Final = 1.0
"""Sim time the first leg of a stand-up, from wherever the robot is to the squat, takes."""
UPPER_KP: Final = 3000.0
UPPER_KD: Final = 100.0
"""Waist and arms while walking (measured: kp 300 kd 5 lets a straight walk curve metres sideways)."""
DAMP_KD: Final = np.array([120.0] * 12 + [120.0] * 3 + [1.0] * 14)
MAX_VX: Final = 1.0
MAX_VY: Final = 0.5
MAX_WZ: Final = 1.0
"""Velocity commands are clipped to these (m/s, m/s, rad/s): the range the policy handles."""
HEADING_KP: Final = 1.0
HEADING_MAX_WZ: Final = 0.3
"""Heading hold while walking with no yaw rate commanded: yaw rate = HEADING_KP x heading error (1/s),
at most HEADING_MAX_WZ rad/s. The policy has no heading in its observation, so a straight command drifts
in yaw with every disturbance (measured over the wire on a loaded machine: 1.2 m sideways in 10 s);
the robot's own controller keeps its heading from the IMU the same way."""
MAX_DURATION_S: Final = 864000.0
"""LocoClient.Move(continous_move=True) sends 864000 s."""


def _lerp(a: np.ndarray, b: np.ndarray, ratio: float) -> np.ndarray:
    return (1.0 - ratio) * a + ratio * b


@dataclass(frozen=True)
class Squat:
    """The robot's own squat and the gains that hold it: its control file's pose and floating-mode gains
    (robots/unitree_g1/control.toml), as the sim serves them on info/robot; the controller keeps no copy.

    Sit and stand-to-squat go to this crouch, a stand-up ramps through it, and every ramp holds its pose
    with these gains (measured: kp 200 on the ankles lets a robot that sagged in damp tip over backwards
    on the way up; the floating gains, on which the robot stands at spawn, hold it)."""

    q: np.ndarray
    kp: np.ndarray
    kd: np.ndarray

    @classmethod
    def of(cls, info: RobotInfo) -> Squat:
        floating = info.gains["floating"]
        return cls(np.asarray(info.default_q["floating"], float), np.asarray(floating.kp, float),
                   np.asarray(floating.kd, float))


@dataclass
class Targets:
    """Motor targets for every joint (canonical order)."""

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray

    @classmethod
    def hold(cls, q: np.ndarray, kp: np.ndarray, kd: np.ndarray) -> Targets:
        zeros = np.zeros(NUM_JOINTS)
        return cls(np.array(q, float), zeros, np.array(kp, float), np.array(kd, float), zeros.copy())


@dataclass
class ArmSdk:
    """The newest rt/arm_sdk command: waist and arm targets (motors 12..28) and the weight."""

    weight: float
    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray


@dataclass
class Velocity:
    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0
    until_s: float = 0.0
    """Sim time at which the command lapses (a duration of 1 s by default in LocoClient.Move)."""


@dataclass
class LocoState:
    """What the sport service reports (GetFsmId and friends) and SportModeState_ carries."""

    fsm_id: int = FSM_ZERO_TORQUE
    active: bool = False
    """False until the first FSM request: the controller sends nothing."""
    walking: bool = False
    """The policy runs (start, or squat-to-stand after its ramp)."""
    balance_mode: int = 0
    velocity: Velocity = field(default_factory=Velocity)


class LocoController:
    """The FSM, the ramps, the policy and the arm_sdk blend (see the module docstring)."""

    def __init__(self, squat: Squat | None = None, policy: WalkPolicy | None = None) -> None:
        self.squat = squat
        """The robot's squat (Squat.of its info/robot); None until a robot is adopted: no mode can start."""
        self.policy = policy or WalkPolicy()
        self.state = LocoState()
        self.arm_sdk: ArmSdk | None = None
        self._ramp_from: np.ndarray | None = None
        self._ramp_to = STAND_Q
        self._ramp_start_s: float | None = None
        self._then_walk = False
        self._action = np.zeros(NUM_ACTIONS, np.float32)
        self._next_tick_s: float | None = None
        self._last_now_s: float | None = None
        self._heading_ref: float | None = None
        self._leg_targets = DEFAULT_LEG_Q.copy()
        self.policy_steps = 0

    # --- requests (the sport service) ------------------------------------------------

    def set_fsm(self, fsm_id: int) -> None:
        """Switch the FSM. Raises ValueError for an id the controller does not run."""
        if fsm_id not in FSM_IDS:
            raise ValueError(f"FSM id {fsm_id} is not one of {FSM_IDS}")
        if self.squat is None:
            raise ValueError("no robot yet: its squat and gains come from its info/robot")
        squat = self.squat
        state = self.state
        standing = state.active and state.walking  # a finished stand-up hands over to walking
        state.active = True
        state.walking = False
        state.velocity = Velocity()
        self._ramp_start_s = None
        self._next_tick_s = None  # tick at the next state (a reset may just have moved sim time back)
        if fsm_id == FSM_SQUAT_STAND and standing:
            self._start_ramp(squat.q, then_walk=False)
        elif fsm_id == FSM_SIT:
            self._start_ramp(squat.q, then_walk=False)
        elif fsm_id in (FSM_SQUAT_STAND, FSM_LIE_TO_STAND):
            self._start_ramp(STAND_Q, then_walk=True)
        elif fsm_id == FSM_START:
            if standing:
                self._begin_walk()
            else:
                self._start_ramp(STAND_Q, then_walk=True)
        state.fsm_id = fsm_id

    def set_velocity(self, vx: float, vy: float, wz: float, duration_s: float, now_s: float) -> None:
        """Walk at (vx, vy, wz) for `duration_s` of sim time from `now_s` (clipped to the policy's range).

        Raises:
            ValueError: a non-finite value or a negative duration.
        """
        values = (vx, vy, wz, duration_s)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"velocity and duration must be finite, got {values}")
        if duration_s < 0:
            raise ValueError(f"duration must not be negative, got {duration_s}")
        self._heading_ref = None  # a new command: hold the heading the robot has when it starts
        self.state.velocity = Velocity(
            float(np.clip(vx, -MAX_VX, MAX_VX)), float(np.clip(vy, -MAX_VY, MAX_VY)),
            float(np.clip(wz, -MAX_WZ, MAX_WZ)), now_s + min(duration_s, MAX_DURATION_S))

    def release(self) -> None:
        """Stop sending (the motion switcher's ReleaseMode, a sim reset): passive, as at start."""
        self.state = LocoState()
        self._ramp_start_s = None
        self._next_tick_s = None

    # --- arm_sdk -------------------------------------------------------------------------

    def set_arm_sdk(self, q: np.ndarray, dq: np.ndarray, kp: np.ndarray, kd: np.ndarray, tau: np.ndarray,
                    weight: float) -> None:
        """Take one rt/arm_sdk command (motors 12..28 and the weight, clipped to [0, 1])."""
        self.arm_sdk = ArmSdk(float(np.clip(weight, 0.0, 1.0)), q, dq, kp, kd, tau)

    # --- the loop ------------------------------------------------------------------------

    def command_now(self, now_s: float) -> np.ndarray:
        """The velocity command in force at `now_s` (zero once it lapsed)."""
        v = self.state.velocity
        if now_s >= v.until_s:
            return np.zeros(3)
        return np.array([v.vx, v.vy, v.wz])

    def tick(self, now_s: float, q: Sequence[float], dq: Sequence[float], quat_wxyz: Sequence[float],
             gyro: Sequence[float], force: bool = False) -> Targets | None:
        """Targets for the instant `now_s` of the sim, or None: while passive, and between ticks.

        The controller ticks once per CONTROL_DT_S of sim time (the policy's 50 Hz; one tick per state
        under the lockstep clock, whose commands advance 20 ms each); `force` ticks now (a new request).
        """
        state = self.state
        if not state.active:
            return None
        went_back = self._last_now_s is not None and now_s < self._last_now_s - CONTROL_DT_S
        self._last_now_s = now_s
        if went_back:
            # Sim time went back: a reset (or a restarted sim) put the robot back into its spawn squat.
            # The current mode starts over from there: a ramp from the present pose, walking by standing
            # up first (the policy on a robot just dropped into a squat would throw it over); a velocity
            # command lapses. Requests that raced the reset land in the new episode either way.
            self._next_tick_s = None
            self._ramp_start_s = None
            state.velocity = Velocity()
            if state.walking:
                state.walking = False
                self._start_ramp(STAND_Q, then_walk=True)
        due = self._next_tick_s is None or now_s >= self._next_tick_s - 1e-9
        if not (due or force):
            return None
        base = now_s if self._next_tick_s is None or not due else self._next_tick_s
        self._next_tick_s = max(base + CONTROL_DT_S, now_s + 1e-6)
        q_now, dq_now = np.asarray(q, float), np.asarray(dq, float)
        quat_now, gyro_now = np.asarray(quat_wxyz, float), np.asarray(gyro, float)
        if state.fsm_id == FSM_ZERO_TORQUE:
            zeros = np.zeros(NUM_JOINTS)
            targets = Targets.hold(q_now, zeros, zeros)
        elif state.fsm_id == FSM_DAMP:
            targets = Targets.hold(q_now, np.zeros(NUM_JOINTS), DAMP_KD)
        elif state.walking:
            targets = self._walk(now_s, q_now, dq_now, quat_now, gyro_now)
        else:
            targets = self._ramp(now_s, q_now, dq_now, quat_now, gyro_now)
        return self._blend_arms(targets)

    def _start_ramp(self, to: np.ndarray, then_walk: bool) -> None:
        self._ramp_from = None  # taken from the first state after the request
        self._ramp_to = to
        self._ramp_start_s = None
        self._then_walk = then_walk

    def _ramp(self, now_s: float, q, dq, quat_wxyz, gyro) -> Targets:  # noqa: ANN001
        if self._ramp_start_s is None or self._ramp_from is None:
            self._ramp_start_s = now_s
            self._ramp_from = np.array(q, float)
        ramp_from: np.ndarray = self._ramp_from
        elapsed = now_s - self._ramp_start_s
        squat = self.squat
        assert squat is not None, "set_fsm refuses to start a ramp without the robot's squat"
        if self._ramp_to is STAND_Q:
            # Through the squat: straight from a deep crouch to the stance in joint space moves the
            # centre of mass behind the feet (measured: it falls backwards); from the squat it does not.
            if elapsed < SQUAT_S:
                return Targets.hold(_lerp(ramp_from, squat.q, elapsed / SQUAT_S), squat.kp, squat.kd)
            start, elapsed = squat.q, elapsed - SQUAT_S
        else:
            start = ramp_from
        ratio = min(1.0, elapsed / STAND_UP_S)
        if ratio >= 1.0 and self._then_walk:
            self._begin_walk()
            return self._walk(now_s, q, dq, quat_wxyz, gyro)
        return Targets.hold(_lerp(start, self._ramp_to, ratio), squat.kp, squat.kd)

    def _begin_walk(self) -> None:
        self.state.walking = True
        self.policy.reset()
        self._action[:] = 0.0
        self._leg_targets = DEFAULT_LEG_Q.copy()

    def _walk(self, now_s: float, q, dq, quat_wxyz, gyro) -> Targets:  # noqa: ANN001
        obs = observation(gyro, quat_wxyz, self._held_heading(self.command_now(now_s), quat_wxyz),
                          q[:NUM_ACTIONS], dq[:NUM_ACTIONS], self._action, now_s)
        self._action = self.policy.act(obs)
        self._leg_targets = self.policy.leg_targets(self._action)
        self.policy_steps += 1
        kp = np.concatenate([LEG_KP, np.full(NUM_JOINTS - NUM_ACTIONS, UPPER_KP)])
        kd = np.concatenate([LEG_KD, np.full(NUM_JOINTS - NUM_ACTIONS, UPPER_KD)])
        pose = np.concatenate([self._leg_targets, np.zeros(NUM_JOINTS - NUM_ACTIONS)])
        return Targets.hold(pose, kp, kd)

    def _held_heading(self, command: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
        """The command with a yaw rate that holds the heading while walking straight (HEADING_KP)."""
        if command[2] != 0.0 or not (command[0] or command[1]):
            self._heading_ref = None
            return command
        w, x, y, z = quat_wxyz
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        if self._heading_ref is None:
            self._heading_ref = yaw
        error = (self._heading_ref - yaw + math.pi) % (2 * math.pi) - math.pi
        held = command.copy()
        held[2] = float(np.clip(HEADING_KP * error, -HEADING_MAX_WZ, HEADING_MAX_WZ))
        return held

    def _blend_arms(self, targets: Targets) -> Targets:
        arm = self.arm_sdk
        if arm is None or arm.weight <= 0.0:
            return targets
        w, s = arm.weight, slice(ARM_SDK_FIRST, NUM_JOINTS)
        for name in ("q", "dq", "kp", "kd", "tau"):
            mine = getattr(targets, name)
            blended = w * getattr(arm, name) + (1.0 - w) * mine[s]
            if name in ("kp", "kd"):  # the waist keeps the controller's stiffness (module docstring)
                blended[:NUM_WAIST] = mine[ARM_SDK_FIRST:ARM_SDK_FIRST + NUM_WAIST]
            mine[s] = blended
        return targets
