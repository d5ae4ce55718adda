"""Build a simulation-ready MuJoCo model from a URDF and its control.toml.

A URDF describes links and joints only. This module completes it the way the ROS seed's launch files
did (floating base or a welded base, a floor, PD motors, IMU) and adds what MuJoCo needs to stay
stable: rotor armature, mass/inertia floors, the implicitfast integrator. Each compile starts from a
fresh MjSpec because compiling mutates the spec.

Motors follow Unitree LowCmd semantics, tau = kp*(q - q_meas) + kd*(dq - dq_meas) + tau_ff, as a
MuJoCo `general` actuator with gain 1 and an affine bias [0, -kp, -kd]: MuJoCo then integrates the
damping term implicitly, which an explicit PD computed in Python cannot do at kd 50 on light joints.
"""

from __future__ import annotations

import fnmatch
import functools
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import mujoco
import numpy as np

from zensim.robots import RobotFiles
from zensim.schemas.messages import MODES, Mode, Terrain
from zensim.robots.control import DEFAULT_ARMATURE_KG_M2, ControlConfig, ModeConfig, first_match, load_control
from zensim.robots.description import Description, Joint, RobotModelError, parse_urdf
from zensim.robots.mesh_files import resolve_mesh
from zensim.robots import terrain as terrain_shapes

__all__ = ["MODES", "ModeFigures", "Placement", "Robot", "RobotModelError", "build", "build_with_mjcf", "build_world",
           "mode_figures", "place_base"]

logger = logging.getLogger(__name__)


FREE_JOINT_NAME: Final = "floating_base"
FLOOR_NAME: Final = "floor"
SPAWN_CLEARANCE_M: Final = 0.002
"""Gap left under the lowest point when the spawn height is derived from the model."""
DEFAULT_KP_PER_EFFORT: Final = 2.0
"""Default stiffness without a control file: full effort at 0.5 rad of error (kp = 2 * effort)."""
DEFAULT_KD_RATIO: Final = 0.05
"""Default damping as a fraction of kp."""
DEFAULT_KP_NO_EFFORT: Final = 100.0
"""Default stiffness for joints whose URDF gives no effort limit."""

# Contact bits: robot geoms carry ROBOT_BIT in contype and FLOOR_BIT in conaffinity, the floor both.
# A pair collides when (contype_a & conaffinity_b) | (contype_b & conaffinity_a), so robot-robot
# pairs never do (2 & 1 == 0) while robot-floor pairs do.
FLOOR_BIT: Final = 1
ROBOT_BIT: Final = 2

_INTEGRATORS: Final = {
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SENSORS: Final = {
    # name: (type, object type, which object: "imu" site or "base" body, dimension)
    "imu_quat": (mujoco.mjtSensor.mjSENS_FRAMEQUAT, mujoco.mjtObj.mjOBJ_SITE, "imu", 4),
    "imu_gyro": (mujoco.mjtSensor.mjSENS_GYRO, mujoco.mjtObj.mjOBJ_SITE, "imu", 3),
    "imu_accel": (mujoco.mjtSensor.mjSENS_ACCELEROMETER, mujoco.mjtObj.mjOBJ_SITE, "imu", 3),
    # XBODY: the link frame; BODY would report the centre of mass.
    "base_pos": (mujoco.mjtSensor.mjSENS_FRAMEPOS, mujoco.mjtObj.mjOBJ_XBODY, "base", 3),
    "base_quat": (mujoco.mjtSensor.mjSENS_FRAMEQUAT, mujoco.mjtObj.mjOBJ_XBODY, "base", 4),
    "base_linvel": (mujoco.mjtSensor.mjSENS_FRAMELINVEL, mujoco.mjtObj.mjOBJ_XBODY, "base", 3),
    "base_angvel": (mujoco.mjtSensor.mjSENS_FRAMEANGVEL, mujoco.mjtObj.mjOBJ_XBODY, "base", 3),
}
# Each foot link (control.toml `foot_links`) carries two MuJoCo contact sensors over every contact of its
# body (the floor, terrain, another robot). They are computed in the acceleration stage of a step (from the
# constraint forces it solved), so between steps sensordata holds the forces that acted during the step
# that just ended, like the accelerometer. A contact force read between steps with mj_contactForce would
# read the solver's arrays of the step before, laid out for the contacts of the step before.
FOOT_NET_SUFFIX: Final = "_contact_net"
"""The net contact force on the foot: [contacts found, force (3, world frame, exerted BY the foot)]."""
FOOT_NET_DIM: Final = 4
FOOT_POINTS_SUFFIX: Final = "_contact_points"
"""The strongest contacts of the foot, each its force in its own contact frame (normal first)."""
FOOT_POINTS: Final = 8
"""Contacts of one foot whose normal forces are summed (the strongest first); a G1 sole (a box on the floor)
makes 4. A foot with more loses the weakest from its normal force (not from its net force)."""
_CONTACT_DATA_FOUND: Final = 1 << int(mujoco.mjtConDataField.mjCONDATA_FOUND)
_CONTACT_DATA_FORCE: Final = 1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE)
_CONTACT_REDUCE_MAXFORCE: Final = 2
"""A contact sensor's `reduce` (intprm[1]), as MJCF's reduce="maxforce": the strongest contacts first."""
_CONTACT_REDUCE_NETFORCE: Final = 3
"""reduce="netforce": one synthetic contact carrying the sum of the forces, in the world frame."""


@dataclass
class Robot:
    """A compiled robot and everything a simulator needs to drive it, in canonical joint order."""

    model: mujoco.MjModel
    mode: Mode
    name: str
    joint_names: tuple[str, ...]
    q_min: np.ndarray
    q_max: np.ndarray
    effort_limit: np.ndarray
    velocity_limit: np.ndarray
    default_q: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    base_height_m: float
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    actuator_ids: np.ndarray
    base_body_id: int
    control: ControlConfig
    urdf_path: Path
    urdf_text: str
    mesh_files: dict[str, Path]
    base_link: str = ""
    imu_site_id: int = -1
    free_qpos_adr: int = -1
    """qpos address of the free joint (floating mode), -1 in the fixed mode."""
    free_dof_adr: int = -1
    sensor_slices: dict[str, slice] = field(default_factory=dict)
    """Name -> slice of data.sensordata for the sensors in _SENSORS, and each foot's contact sensors
    (`{link}_contact_net`, `{link}_contact_points`)."""
    foot_links: tuple[str, ...] = ()
    """The links matching control.toml's `foot_links`, in the URDF's order (the G1: left, then right)."""
    armature: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Rotor armature per joint, kg m^2, canonical order."""
    control_path: Path | None = None
    """The control file used, None for defaults."""
    spawn_xy: tuple[float, float] = (0.0, 0.0)
    """Where the base stands in the world's x, y, m (a robot of a world; 0, 0 alone)."""
    spawn_yaw_rad: float = 0.0
    """Heading of the base at spawn, rad about the world's z."""
    slot: WorldSlot | None = None
    """Where this robot lies in a model it shares with other robots (build_world); None: it owns the model."""

    @property
    def nu(self) -> int:
        """Number of actuated joints."""
        return len(self.joint_names)


@dataclass(frozen=True)
class Placement:
    """One robot of a world: its name prefix in the shared model, its files and where it spawns."""

    prefix: str
    files: RobotFiles
    xy: tuple[float, float] = (0.0, 0.0)
    yaw_rad: float = 0.0
    mode: Mode | None = None
    """This robot's mode (a fixed robot stands welded on its stand in the world); None: the world's."""


@dataclass(frozen=True)
class WorldSlot:
    """The ranges of a shared model's arrays that belong to one robot (contiguous: attached in turn)."""

    qpos: slice
    dof: slice
    bodies: slice
    actuators: slice


# ------------------------------------------------------------------------------------- resolution
def _default_gains(effort: float) -> tuple[float, float]:
    kp = DEFAULT_KP_PER_EFFORT * effort if math.isfinite(effort) else DEFAULT_KP_NO_EFFORT
    return kp, DEFAULT_KD_RATIO * kp


def resolve_gains(mode_cfg: ModeConfig, joints: tuple[Joint, ...]) -> tuple[np.ndarray, np.ndarray]:
    """kp, kd per joint for one mode: first matching group, else derived from the effort limit."""
    groups = [(g.joints, (g.kp, g.kd)) for g in mode_cfg.gains]
    pairs = [first_match(j.name, groups) or _default_gains(j.effort) for j in joints]
    return np.array([p[0] for p in pairs], float), np.array([p[1] for p in pairs], float)


def resolve_pose(control: ControlConfig, joints: tuple[Joint, ...]) -> np.ndarray:
    """Default joint positions, clipped into the joint limits (a zero pose may lie outside them)."""
    groups = [([pattern], value) for pattern, value in control.pose.items()]
    q = np.array([0.0 if (value := first_match(j.name, groups)) is None else float(value) for j in joints])
    lo = np.array([j.lower for j in joints])
    hi = np.array([j.upper for j in joints])
    clipped = np.clip(q, lo, hi)
    for j, before, after in zip(joints, q, clipped):
        if before != after:
            logger.warning("default pose of %s (%.3f) is outside its limits; using %.3f", j.name, before, after)
    return clipped


def resolve_armature(control: ControlConfig, joints: tuple[Joint, ...]) -> np.ndarray:
    """Armature per joint, kg m^2: first matching group, else DEFAULT_ARMATURE_KG_M2.

    An explicit 0.0 is a value, not "unset": `first_match(...) or default` turned it into the default.
    """
    groups = [(g.joints, g.value) for g in control.armature]
    matched = [first_match(j.name, groups) for j in joints]
    return np.array([DEFAULT_ARMATURE_KG_M2 if value is None else float(value) for value in matched])


# ------------------------------------------------------------------------------------------- spec
@dataclass
class _Prepared:
    spec: mujoco.MjSpec
    info: Description
    joints: tuple[Joint, ...]
    """The actuated joints, canonical order."""
    control: ControlConfig
    text: str
    mesh_files: dict[str, Path]
    base_link: str
    imu_link: str
    kp: np.ndarray
    kd: np.ndarray
    default_q: np.ndarray
    armature: np.ndarray
    foot_links: tuple[str, ...] = ()


def _apply_inertia_floors(spec: mujoco.MjSpec, mass_floor: float, inertia_floor: float) -> None:
    """Raise mass and principal inertia of bodies that carry a joint to the floors.

    Only moving bodies: MuJoCo's own compiler.boundmass would also give mass to the massless sensor
    frames (imu_in_pelvis, d435_link) and the 1 g decorative links, adding tens of grams the robot
    does not have. Raising the diagonal of a full inertia keeps it positive definite.
    """
    for body in spec.bodies:
        if body.name == "world" or not body.joints:
            continue
        if body.mass < mass_floor:
            body.mass = mass_floor
        if body.explicitinertial and not np.isnan(body.fullinertia[0]):
            full = np.array(body.fullinertia)
            full[:3] = np.maximum(full[:3], inertia_floor)
            body.fullinertia = full
        else:
            body.inertia = np.maximum(np.array(body.inertia), inertia_floor)


def _prepare(files: RobotFiles, mode: Mode, terrain: Terrain | None = None) -> _Prepared:
    """Load the URDF into a fresh MjSpec and complete it for `mode`."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    control = load_control(files.control)
    text = files.urdf.read_text()
    info = parse_urdf(text)
    joints = info.actuated_joints
    if not joints:
        raise RobotModelError(f"{files.urdf}: no actuated (revolute/continuous/prismatic) joints")
    urdf_dir = files.urdf.parent
    mesh_files = {name: resolve_mesh(name, urdf_dir) for name in info.mesh_filenames}
    model_cfg = control.model
    base_link = model_cfg.base_link or info.root_link
    imu_link = model_cfg.imu_link or base_link
    for what, link in (("model.base_link", base_link), ("model.imu_link", imu_link)):
        if link not in info.links:
            raise RobotModelError(f"{files.control}: {what} = {link!r} is not a link of {files.urdf}")
    if base_link != info.root_link:
        raise RobotModelError(f"model.base_link {base_link!r} must be the URDF root link {info.root_link!r}")
    mode_cfg: ModeConfig = getattr(control, mode)

    spec = mujoco.MjSpec.from_file(str(files.urdf))
    spec.compiler.discardvisual = True
    spec.compiler.fusestatic = False  # else the jointless pelvis fuses into the world with its mass
    spec.compiler.meshdir = str(urdf_dir)
    _apply_inertia_floors(spec, model_cfg.mass_floor_kg, model_cfg.inertia_floor_kg_m2)
    # Absolute mesh paths resolved like a viewer resolves them; no path stripping needed then.
    spec.strippath = False
    for mesh in spec.meshes:
        key = mesh.file if mesh.file in mesh_files else next(
            (k for k in mesh_files if Path(k).name == Path(mesh.file).name), None)
        if key is None:
            raise RobotModelError(f"MuJoCo mesh {mesh.file!r} has no match among the URDF meshes")
        mesh.file = str(mesh_files[key])

    spec.option.timestep = model_cfg.timestep_s
    spec.option.integrator = _INTEGRATORS[model_cfg.integrator]
    spec.option.gravity = [0.0, 0.0, -9.81] if mode_cfg.gravity else [0.0, 0.0, 0.0]

    base = spec.body(base_link)
    base.pos = [0.0, 0.0, mode_cfg.base_height_m or 0.0]
    if mode == "floating":
        base.add_freejoint(name=FREE_JOINT_NAME)

    kp, kd = resolve_gains(mode_cfg, joints)
    default_q = resolve_pose(control, joints)
    armature = resolve_armature(control, joints)
    for j, arm, kp_j, kd_j in zip(joints, armature, kp, kd):
        spec.joint(j.name).armature = float(arm)
        act = spec.add_actuator(name=j.name, target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = 1.0
        # The mode's default gains, so the written MJCF reads as a PD; the sim rewrites them at every command (zensim.sim.mjdata).
        act.biasprm[1], act.biasprm[2] = -float(kp_j), -float(kd_j)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE  # the joint's actfrcrange clips the total

    robot_geoms = list(spec.geoms)
    for geom in robot_geoms:
        if not model_cfg.self_collision:
            geom.contype, geom.conaffinity = ROBOT_BIT, FLOOR_BIT
        body_name = geom.parent.name
        if any(fnmatch.fnmatchcase(body_name, p) for p in model_cfg.foot_links):
            geom.friction = [model_cfg.foot_friction, geom.friction[1], geom.friction[2]]

    world = spec.worldbody
    # The fixed mode is a robot on a stand: welded at the seed's classic height (0.79 m for the G1),
    # where users expect every joint to move through its whole range. There the floor only gets in
    # the way (the G1's straight legs reach 2.3 mm below 0.79 m, and a welded base pushes back with
    # any force), so the floor is drawn but collides with nothing; the height stays the one users know.
    floor_bits = FLOOR_BIT | ROBOT_BIT if mode == "floating" else 0
    world.add_geom(name=FLOOR_NAME, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05],
                   friction=[model_cfg.floor_friction, 0.005, 0.0001], contype=floor_bits,
                   conaffinity=floor_bits, rgba=[0.5, 0.55, 0.6, 1.0])
    if terrain is not None:  # on the floor, colliding as it does
        terrain_shapes.add_to_spec(spec, terrain, floor_bits, floor_bits, [model_cfg.floor_friction, 0.005, 0.0001])
    world.add_light(name="sun", pos=[0.0, 0.0, 4.0], dir=[0.0, 0.0, -1.0], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)

    spec.body(imu_link).add_site(name=model_cfg.imu_site)
    for name, (stype, otype, which, _dim) in _SENSORS.items():
        spec.add_sensor(name=name, type=stype, objtype=otype,
                        objname=model_cfg.imu_site if which == "imu" else base_link)
    feet = tuple(body.name for body in spec.bodies
                 if any(fnmatch.fnmatchcase(body.name, p) for p in model_cfg.foot_links))
    for foot in feet:
        _add_foot_sensors(spec, foot)
    return _Prepared(spec, info, joints, control, text, mesh_files, base_link, imu_link, kp, kd, default_q, armature,
                     feet)


def _add_foot_sensors(spec: mujoco.MjSpec, link: str) -> None:
    """A foot's two contact sensors (FOOT_NET_SUFFIX, FOOT_POINTS_SUFFIX) over the contacts of its body."""
    for suffix, data, reduce, num in (
            (FOOT_NET_SUFFIX, _CONTACT_DATA_FOUND | _CONTACT_DATA_FORCE, _CONTACT_REDUCE_NETFORCE, 1),
            (FOOT_POINTS_SUFFIX, _CONTACT_DATA_FORCE, _CONTACT_REDUCE_MAXFORCE, FOOT_POINTS)):
        sensor = spec.add_sensor(name=link + suffix, type=mujoco.mjtSensor.mjSENS_CONTACT,
                                 objtype=mujoco.mjtObj.mjOBJ_BODY, objname=link)
        sensor.intprm[0], sensor.intprm[1], sensor.intprm[2] = data, reduce, num


def _compile(prepared: _Prepared, files: RobotFiles) -> mujoco.MjModel:
    try:
        return prepared.spec.compile()
    except ValueError as exc:  # MuJoCo raises ValueError for compile errors
        raise RobotModelError(f"MuJoCo could not compile {files.urdf}: {exc}") from exc


def _lowest_point_z(model: mujoco.MjModel, data: mujoco.MjData, slot: WorldSlot | None = None) -> float:
    """Lowest z over the robot's collision geoms' bounding boxes (floor and terrain excluded; in a world, its own
    geoms)."""
    lowest = math.inf
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    ground = terrain_shapes.ground_geoms(model)
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        if ground[g] or (slot is not None and not slot.bodies.start <= body < slot.bodies.stop):
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners = centre + signs * half
        world = data.geom_xpos[g] + corners @ data.geom_xmat[g].reshape(3, 3).T
        lowest = min(lowest, float(world[:, 2].min()))
    return lowest


def build(files: RobotFiles, mode: Mode, terrain: Terrain | None = None) -> Robot:
    """Compile a robot for one mode.

    Args:
        files: The URDF and control file (see `robot_files`).
        mode: "floating" (free base on the floor, gravity per control.toml) or "fixed" (base welded
            at `fixed.base_height_m`, gravity off by default).
        terrain: slopes, stairs, rough ground... on the floor (robots/terrain.py); None: the flat floor.

    Returns:
        The compiled robot; its model holds one actuator per actuated joint in URDF order.

    Raises:
        RobotModelError: Unusable URDF/control content or a MuJoCo compile error.
        ControlConfigError: A control file that does not decode (names the field).
        FileNotFoundError: A missing URDF, control or mesh file.
    """
    prepared = _prepare(files, mode, terrain)
    model = _compile(prepared, files)
    robot = _robot_from(prepared, model, files, mode)
    _place_spawn(robot)
    return robot


def _robot_from(prepared: _Prepared, model: mujoco.MjModel, files: RobotFiles, mode: Mode, prefix: str = "",
                slot: WorldSlot | None = None) -> Robot:
    """A Robot over `model`, whose elements of this robot carry `prefix` (build_world) or none (build)."""
    info, joints, cfg = prepared.info, prepared.joints, prepared.control
    names = tuple(j.name for j in joints)

    def find(kind: mujoco.mjtObj, name: str) -> int:
        return mujoco.mj_name2id(model, kind, prefix + name)

    jids = np.array([find(mujoco.mjtObj.mjOBJ_JOINT, n) for n in names])
    base_body_id = find(mujoco.mjtObj.mjOBJ_BODY, prepared.base_link)
    free_jid = find(mujoco.mjtObj.mjOBJ_JOINT, FREE_JOINT_NAME)
    sensor_slices = {}
    for name in _SENSORS:
        sid = find(mujoco.mjtObj.mjOBJ_SENSOR, name)
        adr = int(model.sensor_adr[sid])
        sensor_slices[name] = slice(adr, adr + int(model.sensor_dim[sid]))
    for foot in prepared.foot_links:
        for suffix in (FOOT_NET_SUFFIX, FOOT_POINTS_SUFFIX):
            sid = find(mujoco.mjtObj.mjOBJ_SENSOR, foot + suffix)
            adr = int(model.sensor_adr[sid])
            sensor_slices[foot + suffix] = slice(adr, adr + int(model.sensor_dim[sid]))

    return Robot(
        model=model,
        mode=mode,
        name=info.name,
        joint_names=names,
        q_min=np.array([j.lower for j in joints]),
        q_max=np.array([j.upper for j in joints]),
        effort_limit=np.array([j.effort for j in joints]),
        velocity_limit=np.array([j.velocity for j in joints]),
        default_q=prepared.default_q,
        kp=prepared.kp,
        kd=prepared.kd,
        base_height_m=0.0,
        qpos_adr=model.jnt_qposadr[jids].copy(),
        dof_adr=model.jnt_dofadr[jids].copy(),
        actuator_ids=np.array([find(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in names]),
        base_body_id=base_body_id,
        control=cfg,
        urdf_path=files.urdf,
        urdf_text=prepared.text,
        mesh_files=prepared.mesh_files,
        base_link=prepared.base_link,
        imu_site_id=find(mujoco.mjtObj.mjOBJ_SITE, cfg.model.imu_site),
        free_qpos_adr=int(model.jnt_qposadr[free_jid]) if free_jid >= 0 else -1,
        free_dof_adr=int(model.jnt_dofadr[free_jid]) if free_jid >= 0 else -1,
        sensor_slices=sensor_slices,
        armature=prepared.armature,
        control_path=files.control,
        slot=slot,
        foot_links=prepared.foot_links,
    )


def _place_spawn(robot: Robot) -> None:
    """Settle the spawn height (the control file's, else derived from the model) and put the base there."""
    model, mode, cfg = robot.model, robot.mode, robot.control
    height = getattr(cfg, mode).base_height_m
    if height is None:
        # No height in the control file: stand (or hang) just above the floor in the default pose.
        data = mujoco.MjData(model)
        data.qpos[robot.qpos_adr] = robot.default_q
        if robot.free_qpos_adr >= 0:
            data.qpos[robot.free_qpos_adr:robot.free_qpos_adr + 3] = 0.0
        saved = model.body_pos[robot.base_body_id].copy()
        model.body_pos[robot.base_body_id] = 0.0
        mujoco.mj_kinematics(model, data)
        lowest = _lowest_point_z(model, data, robot.slot)
        model.body_pos[robot.base_body_id] = saved
        # A robot with no collision geometry has no lowest point (inf): its base goes at the
        # clearance height, not at -inf, which made every step NaN.
        height = SPAWN_CLEARANCE_M - (lowest if math.isfinite(lowest) else 0.0)
        logger.info("%s: no %s.base_height_m, derived %.4f m from the model's lowest point", robot.name, mode, height)
    if mode == "floating":  # on terrain, the spawn height is over the highest ground under the feet
        height += terrain_shapes.ground_under(robot)
    robot.base_height_m = float(height)
    place_base(robot, robot.base_height_m)


WORLD_COLLISION_GROUPS: Final = 30
"""Robots of a world get contact bits 1..30 in turn: two robots whose places in the world differ by a
multiple of 30 share a bit and pass through each other (MuJoCo has 32 contact bits; bit 0 is the floor)."""


def build_world(placements: list[Placement], mode: Mode, timestep_s: float | None = None,
                terrain: Terrain | None = None) -> list[Robot]:
    """Compile several robots into ONE model (one floor, one MjData), each under its own name prefix.

    Robots touch each other and the floor, but not themselves (as `build` with self_collision off):
    robot k's geoms carry contact bit 1 + k % 30 and accept the floor's bit and every other robot's
    (a fixed robot stands clear of the floor, as in `build`). The timestep and integrator are the
    first robot's; gravity is on when any robot floats (a fixed robot's motors then hold its links up).

    Returns:
        One Robot per placement, in order, all sharing one MjModel; each knows its slot in it.
    """
    if not placements:
        raise ValueError("a world needs at least one robot")
    world = mujoco.MjSpec()
    world.compiler.fusestatic = False
    modes = [placement.mode or mode for placement in placements]
    bits = [1 << (1 + k % WORLD_COLLISION_GROUPS) for k in range(len(placements))]
    all_robots = sum(set(bits))
    # A floating robot stands on the floor; a fixed one is welded on its stand, clear of it (as in `build`).
    on_floor = sum({bit for bit, m in zip(bits, modes) if m == "floating"})
    prepared_list: list[_Prepared] = []
    for k, (placement, robot_mode, bit) in enumerate(zip(placements, modes, bits)):
        prepared = _prepare(placement.files, robot_mode)
        if k == 0:
            world.option.timestep = prepared.spec.option.timestep
            world.option.integrator = prepared.spec.option.integrator
            world.option.gravity = [0.0, 0.0, -9.81] if on_floor else [0.0, 0.0, 0.0]
            floor = prepared.spec.geom(FLOOR_NAME)
            world.worldbody.add_geom(name=FLOOR_NAME, type=floor.type, size=floor.size, friction=floor.friction,
                                     rgba=floor.rgba, contype=FLOOR_BIT, conaffinity=FLOOR_BIT | on_floor)
            if terrain is not None:
                terrain_shapes.add_to_spec(world, terrain, FLOOR_BIT, FLOOR_BIT | on_floor, list(floor.friction))
            world.worldbody.add_light(name="sun", pos=[0.0, 0.0, 4.0], dir=[0.0, 0.0, -1.0],
                                      type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
        for option in ("timestep", "integrator", "gravity"):  # the world's options: no attach conflict
            setattr(prepared.spec.option, option, getattr(world.option, option))
        floor_bit = FLOOR_BIT if robot_mode == "floating" else 0
        for geom in prepared.spec.geoms:
            if geom.parent.name != "world":
                geom.contype, geom.conaffinity = bit, floor_bit | (all_robots & ~bit)
        frame = world.worldbody.add_frame()
        frame.attach_body(prepared.spec.body(prepared.base_link), placement.prefix, "")
        prepared_list.append(prepared)
    try:
        model = world.compile()
    except ValueError as exc:
        raise RobotModelError(f"MuJoCo could not compile the world: {exc}") from exc
    if timestep_s:
        model.opt.timestep = timestep_s
    robots = []
    for placement, prepared, robot_mode in zip(placements, prepared_list, modes):
        slot = _slot_of(model, placement.prefix, prepared.base_link)
        robot = _robot_from(prepared, model, placement.files, robot_mode, placement.prefix, slot)
        robot.spawn_xy, robot.spawn_yaw_rad = placement.xy, placement.yaw_rad
        _place_spawn(robot)
        robots.append(robot)
    return robots


def _slot_of(model: mujoco.MjModel, prefix: str, base_link: str) -> WorldSlot:
    """The contiguous ranges of the bodies, joints and actuators named with `prefix`."""
    def span(kind: mujoco.mjtObj, count: int) -> list[int]:
        return [i for i in range(count) if (mujoco.mj_id2name(model, kind, i) or "").startswith(prefix)]

    bodies = span(mujoco.mjtObj.mjOBJ_BODY, model.nbody)
    joints = span(mujoco.mjtObj.mjOBJ_JOINT, model.njnt)
    actuators = span(mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)
    qpos_start = int(model.jnt_qposadr[joints[0]])
    last = joints[-1]
    qpos_end = int(model.jnt_qposadr[last]) + {0: 7, 1: 4}.get(int(model.jnt_type[last]), 1)
    dof_start = int(model.jnt_dofadr[joints[0]])
    dof_end = int(model.jnt_dofadr[last]) + {0: 6, 1: 3}.get(int(model.jnt_type[last]), 1)
    return WorldSlot(slice(qpos_start, qpos_end), slice(dof_start, dof_end),
                     slice(bodies[0], bodies[-1] + 1), slice(actuators[0], actuators[-1] + 1))


def place_base(robot: Robot, height: float) -> None:
    """Put the base at `height`: the free joint's rest pose (floating) or the weld offset (fixed)."""
    model = robot.model
    if robot.free_qpos_adr >= 0:
        a = robot.free_qpos_adr
        model.qpos0[a:a + 7] = spawn_pose(robot, height)
        model.body_pos[robot.base_body_id] = 0.0
    else:
        model.body_pos[robot.base_body_id] = [*robot.spawn_xy, height]
        if robot.spawn_yaw_rad:
            model.body_quat[robot.base_body_id] = spawn_pose(robot, height)[3:]


def spawn_pose(robot: Robot, height: float) -> list[float]:
    """The free joint's pose at spawn: x, y, z, then the quaternion (w, x, y, z) of the spawn heading."""
    half = robot.spawn_yaw_rad / 2
    return [*robot.spawn_xy, height, math.cos(half), 0.0, 0.0, math.sin(half)]


def build_with_mjcf(files: RobotFiles, mode: Mode) -> tuple[Robot, str]:
    """`build`, and the completed MJCF it compiled, with absolute mesh paths (`zensim robot build`): one compile.

    The MJCF's base height is the control file's, or 0 where the control file leaves it to be derived.
    """
    prepared = _prepare(files, mode)
    model = _compile(prepared, files)
    robot = _robot_from(prepared, model, files, mode)
    _place_spawn(robot)
    return robot, prepared.spec.to_xml()


@dataclass(frozen=True)
class ModeFigures:
    """What a robot is in one mode, for its description (RobotInfo's per-mode fields), without running it."""

    default_q: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    base_height_m: float


def mode_figures(files: RobotFiles, mode: Mode, terrain: Terrain | None = None) -> ModeFigures:
    """A robot's default pose, gains and spawn height in `mode` (`_mode_figures`); on terrain a floating
    robot's spawn height follows the ground under it, which only a build with the terrain tells."""
    if terrain is not None and mode == "floating":
        robot = build(files, mode, terrain)
        return ModeFigures(robot.default_q, robot.kp, robot.kd, robot.base_height_m)
    return _mode_figures(files, mode)


@functools.lru_cache(maxsize=64)  # a world of 32 G1s asks 32 times for the same figures
def _mode_figures(files: RobotFiles, mode: Mode) -> ModeFigures:
    """A robot's default pose, gains and spawn height in `mode`, read from its files.

    Compiles MuJoCo only when the control file leaves the spawn height to be derived from the model: a
    sim describes both modes of its robot, and a world of N robots used to compile each robot's other
    mode once more at start (N extra compiles) only to read these four figures.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    control = load_control(files.control)
    height = getattr(control, mode).base_height_m
    if height is None:
        robot = build(files, mode)
        return ModeFigures(robot.default_q, robot.kp, robot.kd, robot.base_height_m)
    joints = parse_urdf(files.urdf.read_text()).actuated_joints
    kp, kd = resolve_gains(getattr(control, mode), joints)
    return ModeFigures(resolve_pose(control, joints), kp, kd, float(height))
