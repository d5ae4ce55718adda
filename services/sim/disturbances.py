"""Disturbances on one robot: pushes and the elastic band, as forces MuJoCo applies. No network.

Both act through `data.xfrc_applied` (a force at a body's centre of mass, world frame), written on the
thread that steps, before each physics step: a push of `duration_s` acts on exactly round(duration_s /
timestep) whole steps (at least one), from the step after it was accepted, so its impulse is exact and a
lockstep run is the same on every replay. A force is written only to rows this robot owns, and a row
written for a step is cleared at the next step that does not need it: nothing lingers after a push ends,
the band goes off or the robot is reset.

The elastic band is unitree_mujoco's (simulate_python/unitree_sdk2py_bridge.py `ElasticBand`, and
simulate/src/elastic_band.h): a spring-damper from a fixed point above the robot to its base, stiffness
200 N/m, damping 100 N s/m, anchor 3 m up (zensim: 2.2 m above the base's spawn height, where
unitree_mujoco's G1 spawns at 0.79 m), length 0, lowered and raised 0.1 m at a time (its keys 7 and 8).
One difference: unitree_mujoco's is a spring both ways and pushes a robot standing under its rest length
down; this band only pulls (slack below its length, and its damping never makes it push), as a band does.
With the G1 (35 kg) on a band of length 0 the base hangs 1.7 m below the anchor: the feet 0.5 m up.

Everything here is for the thread holding the engine's physics lock (docs/architecture.md, "Threads").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from zensim.robots.builder import Robot
from zensim.schemas import BandRequest, BandState, PushRequest, PushState, short_repr
from zensim.schemas.messages import MAX_BAND_LENGTH_M

STANDARD_GRAVITY_M_S2 = 9.80665
"""For the push bound: a robot's weight is the same in the fixed mode, where the model's gravity is off."""
MAX_PUSH_WEIGHTS = 10.0
"""Largest push, in multiples of the robot's weight (3.4 kN for the G1): ten times what the benchmark of G1
walking policies pushes with (unitree_rl_gym #99: up to a few hundred N), and still far from forces that
break the physics. A force of 1e9 N is a typo or an attack, not a test."""
MAX_ACTIVE_PUSHES = 16
"""Pushes that may act on one robot at once; one more is refused (they add up; 16 cover any scenario)."""
BAND_STIFFNESS_N_M = 200.0
"""unitree_mujoco's ElasticBand.stiffness."""
BAND_DAMPING_N_S_M = 100.0
"""unitree_mujoco's ElasticBand.damping."""
BAND_ANCHOR_ABOVE_SPAWN_M = 2.2
"""The anchor's height above the base's spawn height: unitree_mujoco hangs the G1 (spawned at 0.79 m) from z = 3 m."""
BAND_STEP_M = 0.1
"""What lower and raise change the band's length by (unitree_mujoco's keys 7 and 8)."""


class DisturbanceError(ValueError):
    """A push or band request that does not fit the robot (unknown body, too strong, too many)."""


@dataclass
class Push:
    """One push being applied."""

    body: str
    body_id: int
    force: tuple[float, float, float]
    """World frame, N."""
    start_s: float
    steps: int
    steps_left: int

    def state(self, timestep_s: float) -> PushState:
        duration_s = self.steps * timestep_s
        return PushState(body=self.body, force_n=self.force, start_s=self.start_s, duration_s=duration_s,
                         remaining_s=self.steps_left * timestep_s,
                         impulse_n_s=tuple(f * duration_s for f in self.force))


class Disturbances:
    """The pushes and the band of one robot.

    Args:
        robot: the robot in the world's model.
        data: the world's MjData.
    """

    def __init__(self, robot: Robot, data: mujoco.MjData) -> None:
        self.band_on = False
        self.band_length_m = 0.0
        self.pushes_applied = 0
        self.last_push: PushState | None = None
        self.attach(robot, data)

    def attach(self, robot: Robot, data: mujoco.MjData) -> None:
        """Act on `robot` in `data` from now on (at start and after a rebuild): pushes end, the band stays."""
        self.robot, self.data = robot, data
        model = robot.model
        base_name = model.body(robot.base_body_id).name
        prefix = base_name[: len(base_name) - len(robot.base_link)] if base_name.endswith(robot.base_link) else ""
        # A robot's bodies are those under its base (the world's terrain and other robots are not).
        ids = [b for b in range(1, model.nbody) if model.body_rootid[b] == robot.base_body_id]
        self.bodies = {model.body(b).name.removeprefix(prefix): b for b in ids}
        """The robot's bodies by URDF link name (a robot of a world: without its prefix)."""
        self.weight_n = float(sum(model.body_mass[b] for b in ids)) * STANDARD_GRAVITY_M_S2
        self.max_push_n = MAX_PUSH_WEIGHTS * self.weight_n
        self.floating = robot.free_qpos_adr >= 0
        self.anchor = (*robot.spawn_xy, robot.base_height_m + BAND_ANCHOR_ABOVE_SPAWN_M)
        """The band's fixed point, world frame, m: above the robot's spawn place."""
        self.band_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.pushes: list[Push] = []
        self._written: frozenset[int] = frozenset()
        """Rows of xfrc_applied written for the last step (cleared at the next step that does not need them)."""
        self._push_forces: dict[int, tuple[float, float, float]] | None = None
        """The pushes' force on each body they act on, summed in their order; None: to be summed again (a push
        started or ended since)."""
        self._push_rows: frozenset[int] = frozenset()
        """The rows the pushes write; with the base's (the band's) in _push_rows_band."""
        self._push_rows_band: frozenset[int] = frozenset()
        # Views into `data`'s own arrays (MuJoCo never moves them; a rebuild's new data comes through here):
        # indexing data.xpos or data.qvel anew makes a fresh array each time, a third of the band's cost.
        base = robot.base_body_id
        self._base_only = frozenset((base,))
        self._rows: dict[int, np.ndarray] = {}
        """Each row's force part of xfrc_applied written so far, as a view (`_row`)."""
        self._base_force = self._row(base)
        self._base_pos = data.xpos[base]
        self._base_vel = data.qvel[robot.free_dof_adr:robot.free_dof_adr + 3] if self.floating else None
        """The base's linear velocity, world frame (the free joint's first 3 dofs); None in the fixed mode."""

    # --- requests (physics lock held) ----------------------------------------------------------

    def push(self, request: PushRequest) -> PushState:
        """Start a push at the next step.

        Raises:
            DisturbanceError: an unknown body, a force beyond the bound, too many pushes at once.
        """
        if len(self.pushes) >= MAX_ACTIVE_PUSHES:
            raise DisturbanceError(f"ctl/push: {MAX_ACTIVE_PUSHES} pushes act already; wait for one to end")
        push = self.plan(request)
        self.pushes.append(push)
        self._push_forces = None
        self.pushes_applied += 1
        self.last_push = state = push.state(float(self.robot.model.opt.timestep))
        return state

    def plan(self, request: PushRequest) -> Push:
        """The push `request` asks for, from the next step, checked against the robot but not started.

        Raises:
            DisturbanceError: an unknown body, a force beyond the bound.
        """
        body = request.body or self.robot.base_link
        body_id = self.bodies.get(body)
        if body_id is None:
            known = ", ".join(sorted(self.bodies)[:8])
            raise DisturbanceError(f"ctl/push: no body {short_repr(body)} in {self.robot.name} (its links: {known}, ...)")
        if request.magnitude_n > self.max_push_n:
            raise DisturbanceError(
                f"ctl/push: {request.magnitude_n:g} N is beyond {self.max_push_n:.4g} N, {MAX_PUSH_WEIGHTS:g} x the "
                f"robot's weight ({self.weight_n:.4g} N): no bench pushes that hard; nothing was applied")
        norm = math.sqrt(math.fsum(d * d for d in request.direction))
        fx, fy, fz = (request.magnitude_n * d / norm for d in request.direction)
        force = (fx, fy, fz)
        timestep_s = float(self.robot.model.opt.timestep)
        steps = max(1, round(request.duration_s / timestep_s))
        return Push(body, body_id, force, float(self.data.time), steps, steps)

    def band(self, request: BandRequest) -> BandState:
        """Switch, lower, raise or set the band; an empty request changes nothing.

        Raises:
            DisturbanceError: on in the fixed mode (the base is welded), lower or raise past the bounds.
        """
        self.band_on, self.band_length_m = self.band_after(request)
        return self.band_state()

    def band_after(self, request: BandRequest) -> tuple[bool, float]:
        """Whether the band is on, and its length, once `request` is carried out now; nothing changes here.

        Raises:
            DisturbanceError: on in the fixed mode (the base is welded), lower or raise past the bounds.
        """
        verb, length = request.verb, self.band_length_m
        if verb == "on" and not self.floating:
            raise DisturbanceError("ctl/band: the robot is in the fixed mode, its base welded on its stand: "
                                   "there is nothing to hold")
        if verb == "lower":
            length += BAND_STEP_M
            if length > MAX_BAND_LENGTH_M + 1e-9:
                raise DisturbanceError(f"ctl/band: the band is {self.band_length_m:.3g} m long, at most "
                                       f"{MAX_BAND_LENGTH_M:g}: it cannot be lowered further")
        elif verb == "raise":
            length -= BAND_STEP_M
            if length < -1e-9:
                raise DisturbanceError("ctl/band: the band is at its shortest (0 m): it cannot be raised further")
        if request.length_m is not None:
            length = request.length_m
        return self.band_on if verb not in ("on", "off") else verb == "on", min(max(length, 0.0), MAX_BAND_LENGTH_M)

    def band_state(self) -> BandState:
        return BandState(on=self.band_holds(), anchor=self.anchor, length_m=self.band_length_m,
                         stiffness_n_m=BAND_STIFFNESS_N_M, damping_n_s_m=BAND_DAMPING_N_S_M,
                         force_n=self.band_force)

    def band_holds(self) -> bool:
        """Whether the band acts (on, and a base that can hang: the floating mode)."""
        return self.band_on and self.floating

    def push_states(self) -> tuple[PushState, ...]:
        timestep_s = float(self.robot.model.opt.timestep)
        return tuple(push.state(timestep_s) for push in self.pushes)

    def clear_pushes(self) -> None:
        """End every push now (a reset): their rows are cleared at once."""
        self.pushes.clear()
        self._push_forces = None
        for row in self._written:
            self.data.xfrc_applied[row, :3] = 0.0
        self._written = frozenset()
        self.band_force = (0.0, 0.0, 0.0)

    # --- stepping ------------------------------------------------------------------------------

    def active(self) -> bool:
        """Whether the next step needs `apply` (a force acts, or one written for the last step must go)."""
        return bool(self.pushes) or self.band_holds() or bool(self._written)

    def apply(self) -> None:
        """Before one physics step: write this step's forces (and clear last step's rows no force needs now).

        Plain floats, not numpy: on 3-vectors numpy's call overhead is the cost (the band's force in numpy took
        5 us a step, a sixth of the G1's whole step; benchmarks/disturbances.py). What stays the same from step
        to step is worked out once: the pushes' sums and their rows until a push starts or ends, each row's view
        into xfrc_applied; the band alone, the case that runs for minutes, writes its row and nothing else.
        """
        band = self.band_holds()
        if not self.pushes:
            if band and self._written == self._base_only:
                fx, fy, fz = self.band_force = self._band_force()
                row = self._base_force
                row[0], row[1], row[2] = fx, fy, fz
                return
            forces: dict[int, tuple[float, float, float]] = {}
            rows = self._base_only if band else frozenset()
        else:
            forces = self._push_forces if self._push_forces is not None else self._sum_pushes()
            rows = self._push_rows_band if band else self._push_rows
            ended = False
            for push in self.pushes:
                push.steps_left -= 1
                ended = ended or push.steps_left <= 0
            if ended:  # this step is its last: summed again for the next
                self.pushes = [push for push in self.pushes if push.steps_left > 0]
                self._push_forces = None
        base = self.robot.base_body_id
        if band:
            bx, by, bz = self.band_force = self._band_force()
            pushed = forces.get(base)
            if pushed is not None:
                bx, by, bz = bx + pushed[0], by + pushed[1], bz + pushed[2]
            row = self._base_force
            row[0], row[1], row[2] = bx, by, bz
        for body, (fx, fy, fz) in forces.items():
            if not (band and body == base):
                row = self._row(body)
                row[0], row[1], row[2] = fx, fy, fz
        if self._written != rows:
            for body in self._written - rows:
                row = self._row(body)
                row[0] = row[1] = row[2] = 0.0
            self._written = rows

    def _row(self, body: int) -> np.ndarray:
        """The force part of `body`'s row of xfrc_applied, a view made once."""
        row = self._rows.get(body)
        if row is None:
            row = self._rows[body] = self.data.xfrc_applied[body, :3]
        return row

    def _sum_pushes(self) -> dict[int, tuple[float, float, float]]:
        """The pushes' forces summed per body, and their rows (kept until a push starts or ends)."""
        forces: dict[int, tuple[float, float, float]] = {}
        for push in self.pushes:
            total = forces.get(push.body_id)
            forces[push.body_id] = push.force if total is None else (
                total[0] + push.force[0], total[1] + push.force[1], total[2] + push.force[2])
        self._push_forces = forces
        self._push_rows = frozenset(forces)
        self._push_rows_band = self._push_rows | self._base_only
        return forces

    def _band_force(self) -> tuple[float, float, float]:
        """The band's pull on the base now: spring past its length, damped along it, never a push."""
        ax, ay, az = self.anchor
        px, py, pz = self._base_pos.tolist()
        dx, dy, dz = ax - px, ay - py, az - pz
        distance = math.sqrt(dx * dx + dy * dy + dz * dz)
        if distance <= self.band_length_m or distance == 0.0 or self._base_vel is None:
            return (0.0, 0.0, 0.0)
        ux, uy, uz = dx / distance, dy / distance, dz / distance
        vx, vy, vz = self._base_vel.tolist()  # the base's, world frame
        pull = BAND_STIFFNESS_N_M * (distance - self.band_length_m) - BAND_DAMPING_N_S_M * (vx * ux + vy * uy + vz * uz)
        pull = max(pull, 0.0)
        return (pull * ux, pull * uy, pull * uz)
