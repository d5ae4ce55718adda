"""Randomisation at reset: a variant of one robot drawn from its nominal model (ctl/reset `randomize`). No network.

A controller meant for the real robot should survive a robot that is not quite the model: feet that grip
less, links heavier than the URDF says, a centre of mass off by a centimetre, a motor that gives 85 % of
its torque. `Variants` draws such a variant from a `Randomize` request (seed + ranges) and writes it into
the robot's part of the MjModel, always from the nominal values it captured when the robot was attached,
so a variant never compounds on the one before and a plain reset restores the nominal robot exactly.

The draw is splitmix64 of (seed, stream, index), as the terrain's rough ground (robots/terrain.py): the
same seed and ranges give the same factors on every machine and numpy version.

What each factor changes, and why there:
- friction: the sliding friction of the robot's geoms, as a factor on what its contacts with the ground
  used nominally (MuJoCo takes the larger of the pair: the G1's feet 1.5 on a floor of 1.0). A scaled-down
  foot would hide behind the floor's friction, so while a friction factor applies the robot's geoms get
  a higher priority than the ground's and their friction alone decides (the torsional and rolling parts
  are the pair's nominal larger ones, so only the sliding part moves).
- mass: each link's mass and rotational inertia by one factor (a uniformly denser link), then
  mj_setConst (on scratch data: a world's data holds the other robots) for what MuJoCo derives from the
  masses (subtree masses, inverse weights of the solver).
- com offset: each link's centre of mass (body_ipos) moved in the link's frame.
- motor strength: per joint, the torque limit (jnt_actfrcrange) here and the torque the actuator gives
  (Simulation._apply scales the PD and feed-forward by `strength`).

Everything here is for the thread holding the engine's physics lock.
"""

from __future__ import annotations

from typing import Final

import mujoco
import numpy as np

from zensim.robots.builder import Robot
from zensim.robots.terrain import ground_geoms
from zensim.schemas import Randomize, Variant

STREAM_FRICTION: Final = 1
STREAM_MASS: Final = 2
STREAM_COM: Final = 3
STREAM_STRENGTH: Final = 4
"""Each factor draws from its own stream: adding a range leaves the other factors of a seed as they were."""
_MASK64: Final = (1 << 64) - 1


def uniforms(seed: int, stream: int, n: int) -> np.ndarray:
    """`n` numbers in [0, 1) from splitmix64 of (seed, stream, index): the same on every machine."""
    index = np.arange(n, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = np.uint64(seed & _MASK64) + (np.uint64(stream) << np.uint64(48)) + index + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _factors(seed: int, stream: int, n: int, bounds: tuple[float, float] | None) -> np.ndarray:
    """`n` factors uniform in `bounds` (all 1 when None: that part stays nominal)."""
    if bounds is None:
        return np.ones(n)
    lo, hi = bounds
    return lo + (hi - lo) * uniforms(seed, stream, n)


class Variants:
    """The variant of one robot: the nominal values it is drawn from, and the one in use.

    Args:
        robot: the robot in its (possibly shared) model.
        bodies: the robot's bodies by URDF link name (Disturbances.bodies: one list of a robot's bodies).
    """

    def __init__(self, robot: Robot, bodies: dict[str, int]) -> None:
        model = robot.model
        self.robot = robot
        self.body_names = tuple(bodies)
        self._bodies = np.fromiter(bodies.values(), int, len(bodies))
        self._geoms = np.flatnonzero(np.isin(model.geom_bodyid, self._bodies))
        self._joints = model.dof_jntid[robot.dof_adr]
        """The robot's actuated joints, canonical order."""
        self._mass = model.body_mass[self._bodies].copy()
        self._inertia = model.body_inertia[self._bodies].copy()
        self._ipos = model.body_ipos[self._bodies].copy()
        self._friction = model.geom_friction[self._geoms].copy()
        self._priority = model.geom_priority[self._geoms].copy()
        self._torque_limit = model.jnt_actfrcrange[self._joints].copy()
        self._derived = {name: np.flatnonzero(own) for name, own in (
            ("body_subtreemass", np.isin(np.arange(model.nbody), self._bodies)),
            ("body_invweight0", np.isin(np.arange(model.nbody), self._bodies)),
            ("dof_invweight0", np.isin(model.dof_bodyid, self._bodies)),
            ("dof_M0", np.isin(model.dof_bodyid, self._bodies)),
            ("actuator_acc0", np.isin(np.arange(model.nu), robot.actuator_ids)),
            ("actuator_length0", np.isin(np.arange(model.nu), robot.actuator_ids)))}
        """MuJoCo's constants derived from the masses (mj_setConst), by field: this robot's entries."""
        self._nominal_derived = {name: getattr(model, name)[own].copy() for name, own in self._derived.items()}
        on_ground = ground_geoms(model)  # the floor and the terrain
        ground = model.geom_friction[on_ground]
        ground_max = ground.max(axis=0) if len(ground) else np.zeros(3)
        self._ground_friction = np.maximum(self._friction, ground_max)
        """What each of the robot's geoms nominally used against the ground: the pair's larger friction."""
        self._ground_priority = int(model.geom_priority[on_ground].max(initial=0))
        self.nominal_mass_kg = float(self._mass.sum())
        self.request: Randomize | None = None
        """The request of the variant in use; None: the nominal robot."""
        self.variant: Variant | None = None
        self.strength: np.ndarray | None = None
        """Each motor's torque factor, canonical order; None: nominal (nothing to scale)."""
        self._masses_moved = False
        """Masses or centres of mass differ from nominal: MuJoCo's derived constants were worked out again."""

    def apply(self, request: Randomize | None) -> Variant | None:
        """Make the robot the variant `request` draws (None: the nominal robot), from the nominal values.

        The request was checked whole when it was decoded (schemas Randomize): nothing here can fail
        halfway. The caller resets the data afterwards (mjdata.reset: mj_forward).

        Returns:
            The variant now in use; None: the nominal robot.
        """
        if request is None and self.request is None:  # nominal already: nothing to write
            return None
        model, seed = self.robot.model, 0 if request is None else request.seed
        n_bodies, n_joints = len(self._bodies), len(self._joints)
        ranges = request or Randomize(seed=0)
        friction = float(_factors(seed, STREAM_FRICTION, 1, ranges.friction)[0])
        mass = _factors(seed, STREAM_MASS, n_bodies, ranges.mass)
        offset = (np.zeros((n_bodies, 3)) if ranges.com_offset_m is None else
                  ranges.com_offset_m * (2.0 * uniforms(seed, STREAM_COM, 3 * n_bodies).reshape(n_bodies, 3) - 1.0))
        strength = _factors(seed, STREAM_STRENGTH, n_joints, ranges.motor_strength)

        if ranges.friction is None:
            model.geom_friction[self._geoms] = self._friction
            model.geom_priority[self._geoms] = self._priority
        else:
            scaled = self._ground_friction.copy()
            scaled[:, 0] *= friction
            model.geom_friction[self._geoms] = scaled
            model.geom_priority[self._geoms] = self._ground_priority + 1
        model.body_mass[self._bodies] = self._mass * mass
        model.body_inertia[self._bodies] = self._inertia * mass[:, None]
        model.body_ipos[self._bodies] = self._ipos + offset
        model.jnt_actfrcrange[self._joints] = self._torque_limit * strength[:, None]
        moves_masses = ranges.mass is not None or ranges.com_offset_m is not None
        if moves_masses or self._masses_moved:
            self._derive(nominal=not moves_masses)
        self._masses_moved = moves_masses
        self.strength = None if ranges.motor_strength is None else strength
        self.request = request
        self.variant = None if request is None else Variant(
            seed=request.seed, friction_range=request.friction, mass_range=request.mass,
            com_offset_max_m=request.com_offset_m, motor_strength_range=request.motor_strength,
            friction_scale=friction, bodies=self.body_names, mass_scale=tuple(mass.tolist()),
            com_offset_m=tuple((float(x), float(y), float(z)) for x, y, z in offset.tolist()),
            motor_strength=tuple(strength.tolist()), mass_kg=float(model.body_mass[self._bodies].sum()),
            nominal_mass_kg=self.nominal_mass_kg)
        return self.variant

    def _derive(self, nominal: bool) -> None:
        """Work out again what MuJoCo derives from the masses, for this robot only.

        mj_setConst recomputes the whole model's, and not quite to the bit (1e-13 off the compiler's for a
        robot of a world): the other robots keep theirs as they were, and a robot back to nominal takes the
        compiler's values it was built with, so the nominal robot is the nominal robot to the bit.
        """
        model = self.robot.model
        before = {name: getattr(model, name).copy() for name in self._derived}
        # On scratch data: mj_setConst works in the data it is given, and a world's data holds every robot.
        mujoco.mj_setConst(model, mujoco.MjData(model))
        for name, own in self._derived.items():
            values = getattr(model, name)
            ours = self._nominal_derived[name] if nominal else values[own].copy()
            keep = before[name]
            if name == "body_subtreemass":  # the world body's is every robot's together: the new sum
                keep[0] = values[0]
            values[:] = keep
            values[own] = ours
