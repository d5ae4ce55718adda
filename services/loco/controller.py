"""The walking controller: an FSM, the robot's walking policy, the stand/sit ramps and the arm blend.

No zenoh: `LocoController.tick` takes one instant of the sim (joints, IMU, sim time) and returns the motor
targets for every joint, or None when nothing is to be sent. The service (service.py) calls it for every
sim state and publishes what it returns; everything here runs on sim time, so it behaves the same under
the realtime and the lockstep clock. Every number comes from the robot's walking.toml (`Walking`).

FSM ids (those of unitree_sdk2's LocoClient, which the sport service forwards unchanged):

    0    zero torque      every motor kp = kd = 0: the robot collapses
    1    damp             kp = 0, kd > 0: the robot folds slowly
    3    sit              ramp to the squat, then hold it
    500  start            stand up if needed, then balance and walk (the policy) at the commanded velocity
    702  lie-to-stand     as squat-to-stand (a ramp to the stance: works from a crouch, not from lying flat)
    706  squat-to-stand   ramp through the squat to the stance (squat_s + stand_up_s), then as start;
                          sent while standing (balancing or walking on the policy): stand-to-squat
Before the first FSM request the controller is passive (sends nothing): a low-level program has the robot
to itself until someone asks for a mode; `release` makes it passive again. A sim reset (sim time going
back) restarts the current mode from the spawn squat (walking: it stands up first).

Walking runs the policy every `period_s` of sim time on its leg joints with its trained gains; the other
joints are held stiff at 0 rad (`upper_kp`/`upper_kd`), as in training, where the upper body was welded.
At zero velocity the robot stops stepping: after `settle_s` at zero, at the next instant of the gait with
both feet down, the policy hands over to a ramp to the stance (`plant_s`) held with the ramp gains on
the legs (the upper body keeps its walking gains) (the policy alone steps in place and
creeps ~5 cm a second); the next non-zero command hands back to the policy, fresh.

Arm blend (Unitree's rt/arm_sdk, forwarded on cmd/arms): targets for the arm joints and a weight w in
[0, 1]; each of those joints then gets w x arm + (1 - w) x controller for q, dq, tau, kp and kd (the legs
stay with the controller), except that the `arm_keep_gains` joints (the G1's waist) keep the controller's
gains. The newest arm command holds until the next.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from zensim.robots.walking import Walking

from .walk_policy import WalkPolicy, double_support, load_weights, observation

FSM_ZERO_TORQUE: Final = 0
FSM_DAMP: Final = 1
FSM_SIT: Final = 3
FSM_START: Final = 500
FSM_LIE_TO_STAND: Final = 702
FSM_SQUAT_STAND: Final = 706
FSM_IDS: Final = (FSM_ZERO_TORQUE, FSM_DAMP, FSM_SIT, FSM_START, FSM_LIE_TO_STAND, FSM_SQUAT_STAND)
VERB_FSM: Final = {"zero_torque": FSM_ZERO_TORQUE, "damp": FSM_DAMP, "sit": FSM_SIT, "stand_up": FSM_LIE_TO_STAND,
                   "walk": FSM_START}
"""The ctl/loco verbs as FSM ids (`release` is not a mode: the controller stops sending)."""
MAX_DURATION_S: Final = 864000.0
"""LocoClient.Move(continous_move=True) sends 864000 s."""


def _lerp(a: np.ndarray, b: np.ndarray, ratio: float) -> np.ndarray:
    return (1.0 - ratio) * a + ratio * b


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
        zeros = np.zeros(len(q))
        return cls(np.array(q, float), zeros, np.array(kp, float), np.array(kd, float), zeros.copy())


@dataclass
class ArmBlend:
    """The newest arm command: targets for the arm joints (`Walking.arms` order) and the weight."""

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
    """Sim time at which the command lapses."""


@dataclass
class LocoState:
    """What the controller reports (state/loco; the sport service's GetFsmId and friends)."""

    fsm_id: int = FSM_ZERO_TORQUE
    active: bool = False
    """False until the first FSM request: the controller sends nothing."""
    walking: bool = False
    """The policy balances the robot (start, or squat-to-stand after its ramp), stepping or planted."""
    planted: bool = False
    """Walking at zero velocity: the policy paused, the stance held, both feet on the ground."""
    balance_mode: int = 0
    velocity: Velocity = field(default_factory=Velocity)


class LocoController:
    """The FSM, the ramps, the policy and the arm blend (see the module docstring)."""

    def __init__(self, walking: Walking, policy: WalkPolicy | None = None) -> None:
        self.cfg = walking
        self.policy = policy or WalkPolicy(load_weights(walking.weights), walking.leg_default_q)
        self.state = LocoState()
        self.arm: ArmBlend | None = None
        self._n = len(walking.joints)
        self._ramp_from: np.ndarray | None = None
        self._ramp_to = walking.stand_q
        self._ramp_start_s: float | None = None
        self._then_walk = False
        self._action = np.zeros(len(walking.legs), np.float32)
        self._next_tick_s: float | None = None
        self._last_now_s: float | None = None
        self._heading_ref: float | None = None
        self._still_since_s: float | None = None
        self._plant_from: np.ndarray | None = None
        self._plant_start_s = 0.0
        self.policy_steps = 0
        # Planted: the legs held stiff (the ramp gains), the rest as while walking, so an arm blend sees
        # the same controller gains stepping or not.
        self._plant_kp, self._plant_kd = walking.walk_kp.copy(), walking.walk_kd.copy()
        self._plant_kp[walking.legs], self._plant_kd[walking.legs] = walking.ramp_kp[walking.legs], walking.ramp_kd[walking.legs]

    # --- requests ------------------------------------------------------------------------

    def set_fsm(self, fsm_id: int) -> None:
        """Switch the FSM. Raises ValueError for an id the controller does not run."""
        if fsm_id not in FSM_IDS:
            raise ValueError(f"FSM id {fsm_id} is not one of {FSM_IDS}")
        state = self.state
        standing = state.active and state.walking  # a finished stand-up hands over to walking
        state.active = True
        state.walking = False
        state.planted = False
        state.velocity = Velocity()
        self._ramp_start_s = None
        self._next_tick_s = None  # tick at the next state (a reset may just have moved sim time back)
        if fsm_id == FSM_SQUAT_STAND and standing:
            self._start_ramp(self.cfg.squat_q, then_walk=False)
        elif fsm_id == FSM_SIT:
            self._start_ramp(self.cfg.squat_q, then_walk=False)
        elif fsm_id in (FSM_SQUAT_STAND, FSM_LIE_TO_STAND):
            self._start_ramp(self.cfg.stand_q, then_walk=True)
        elif fsm_id == FSM_START:
            if standing:
                self._begin_walk()
            else:
                self._start_ramp(self.cfg.stand_q, then_walk=True)
        state.fsm_id = fsm_id

    def set_velocity(self, vx: float, vy: float, wz: float, duration_s: float, now_s: float) -> None:
        """Walk at (vx, vy, wz) for `duration_s` of sim time from `now_s` (clipped to the robot's range).

        Raises:
            ValueError: a non-finite value or a negative duration.
        """
        values = (vx, vy, wz, duration_s)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"velocity and duration must be finite, got {values}")
        if duration_s < 0:
            raise ValueError(f"duration must not be negative, got {duration_s}")
        limit = self.cfg.max_velocity
        old = self.state.velocity
        new = Velocity(float(np.clip(vx, -limit[0], limit[0])), float(np.clip(vy, -limit[1], limit[1])),
                       float(np.clip(wz, -limit[2], limit[2])), now_s + min(duration_s, MAX_DURATION_S))
        if (new.vx, new.vy, new.wz) != (old.vx, old.vy, old.wz):
            self._heading_ref = None  # a new command: hold the heading the robot has when it starts
        self.state.velocity = new

    def release(self) -> None:
        """Stop sending (a low-level program takes the motors): passive, as at start."""
        balance_mode = self.state.balance_mode
        self.state = LocoState(balance_mode=balance_mode)
        self._ramp_start_s = None
        self._next_tick_s = None

    def set_arm(self, blend: ArmBlend | None) -> None:
        """Take one arm command (checked first by the caller: the controller blends whatever it is given)."""
        self.arm = blend

    # --- the loop ------------------------------------------------------------------------

    def command_now(self, now_s: float) -> np.ndarray:
        """The velocity command in force at `now_s` (zero once it lapsed)."""
        v = self.state.velocity
        if now_s >= v.until_s:
            return np.zeros(3)
        return np.array([v.vx, v.vy, v.wz])

    def stepping(self, now_s: float) -> bool:
        """Whether the feet move at `now_s`: walking on the policy, not planted."""
        return self.state.active and self.state.walking and not self.state.planted

    def tick(self, now_s: float, q: Sequence[float], dq: Sequence[float], quat_wxyz: Sequence[float],
             gyro: Sequence[float], force: bool = False) -> Targets | None:
        """Targets for the instant `now_s` of the sim, or None: while passive, and between ticks.

        The controller ticks once per `period_s` of sim time (the policy's 50 Hz; one tick per state
        under the lockstep clock, whose commands advance 20 ms each); `force` ticks now (a new request).
        """
        state = self.state
        if not state.active:
            return None
        period = self.cfg.period_s
        went_back = self._last_now_s is not None and now_s < self._last_now_s - period
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
                state.planted = False
                self._start_ramp(self.cfg.stand_q, then_walk=True)
        due = self._next_tick_s is None or now_s >= self._next_tick_s - 1e-9
        if not (due or force):
            return None
        base = now_s if self._next_tick_s is None or not due else self._next_tick_s
        self._next_tick_s = max(base + period, now_s + 1e-6)
        q_now, dq_now = np.asarray(q, float), np.asarray(dq, float)
        quat_now, gyro_now = np.asarray(quat_wxyz, float), np.asarray(gyro, float)
        n = self._n
        if state.fsm_id == FSM_ZERO_TORQUE:
            targets = Targets.hold(q_now, np.zeros(n), np.zeros(n))
        elif state.fsm_id == FSM_DAMP:
            targets = Targets.hold(q_now, np.zeros(n), self.cfg.damp_kd)
        elif state.walking:
            targets = self._walk_or_stand(now_s, q_now, dq_now, quat_now, gyro_now)
        else:
            targets = self._ramp(now_s, q_now, dq_now, quat_now, gyro_now)
        return self._blend_arms(targets)

    def _start_ramp(self, to: np.ndarray, then_walk: bool) -> None:
        self._ramp_from = None  # taken from the first state after the request
        self._ramp_to = to
        self._ramp_start_s = None
        self._then_walk = then_walk

    def _ramp(self, now_s: float, q: np.ndarray, dq: np.ndarray, quat_wxyz: np.ndarray, gyro: np.ndarray) -> Targets:
        cfg = self.cfg
        if self._ramp_start_s is None or self._ramp_from is None:
            self._ramp_start_s = now_s
            self._ramp_from = np.array(q, float)
        ramp_from: np.ndarray = self._ramp_from
        elapsed = now_s - self._ramp_start_s
        if self._ramp_to is cfg.stand_q:
            # Through the squat: straight from a deep crouch to the stance in joint space moves the
            # centre of mass behind the feet (measured: it falls backwards); from the squat it does not.
            if elapsed < cfg.squat_s:
                return Targets.hold(_lerp(ramp_from, cfg.squat_q, elapsed / cfg.squat_s), cfg.ramp_kp, cfg.ramp_kd)
            start, elapsed = cfg.squat_q, elapsed - cfg.squat_s
        else:
            start = ramp_from
        ratio = min(1.0, elapsed / cfg.stand_up_s)
        if ratio >= 1.0 and self._then_walk:
            self._begin_walk()
            return self._walk_or_stand(now_s, q, dq, quat_wxyz, gyro)
        return Targets.hold(_lerp(start, self._ramp_to, ratio), cfg.ramp_kp, cfg.ramp_kd)

    def _begin_walk(self) -> None:
        """The policy takes over from the stance: fresh recurrent state, no previous action."""
        self.state.walking = True
        self.state.planted = False
        self.policy.reset()
        self._action[:] = 0.0
        self._still_since_s = None

    def _walk_or_stand(self, now_s: float, q: np.ndarray, dq: np.ndarray, quat_wxyz: np.ndarray,
                       gyro: np.ndarray) -> Targets:
        """The policy while a velocity is in force (and `settle_s` after); the planted stance otherwise."""
        cfg, state = self.cfg, self.state
        moving = bool(np.any(self.command_now(now_s)))
        if state.planted:
            if not moving:
                ratio = min(1.0, (now_s - self._plant_start_s) / cfg.plant_s)
                assert self._plant_from is not None
                return Targets.hold(_lerp(self._plant_from, cfg.stand_q, ratio), self._plant_kp, self._plant_kd)
            self._begin_walk()  # the next command: the policy starts again from the stance
        if moving:
            self._still_since_s = None
        elif self._still_since_s is None:
            self._still_since_s = now_s
        elif now_s - self._still_since_s >= cfg.settle_s and double_support(now_s):
            state.planted = True
            self._plant_from = np.array(q, float)
            self._plant_start_s = now_s
            return Targets.hold(self._plant_from, self._plant_kp, self._plant_kd)
        return self._walk(now_s, q, dq, quat_wxyz, gyro)

    def _walk(self, now_s: float, q: np.ndarray, dq: np.ndarray, quat_wxyz: np.ndarray, gyro: np.ndarray) -> Targets:
        cfg = self.cfg
        legs = cfg.legs
        obs = observation(gyro, quat_wxyz, self._held_heading(self.command_now(now_s), quat_wxyz),
                          q[legs], dq[legs], self._action, now_s, cfg.leg_default_q)
        self._action = self.policy.act(obs)
        self.policy_steps += 1
        pose = np.zeros(self._n)
        pose[legs] = self.policy.leg_targets(self._action)
        return Targets.hold(pose, cfg.walk_kp, cfg.walk_kd)

    def _held_heading(self, command: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
        """The command with a yaw rate that holds the heading while walking straight (heading_kp)."""
        if command[2] != 0.0 or not (command[0] or command[1]):
            self._heading_ref = None
            return command
        w, x, y, z = quat_wxyz
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        if self._heading_ref is None:
            self._heading_ref = yaw
        error = (self._heading_ref - yaw + math.pi) % (2 * math.pi) - math.pi
        held = command.copy()
        held[2] = float(np.clip(self.cfg.heading_kp * error, -self.cfg.heading_max_wz, self.cfg.heading_max_wz))
        return held

    def _blend_arms(self, targets: Targets) -> Targets:
        arm = self.arm
        if arm is None or arm.weight <= 0.0:
            return targets
        w, idx, keep = arm.weight, self.cfg.arms, self.cfg.arm_keep_gains
        for name in ("q", "dq", "kp", "kd", "tau"):
            mine = getattr(targets, name)
            blended = w * getattr(arm, name) + (1.0 - w) * mine[idx]
            if name in ("kp", "kd"):  # the waist keeps the controller's stiffness (module docstring)
                blended[keep] = mine[idx][keep]
            mine[idx] = blended
        return targets
