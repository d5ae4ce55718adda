"""What runs on MjData at every physics step: apply a motor command, reset, read the base and the IMU.

zensim.robots builds a model (URDF + control.toml -> MjModel + metadata);
this module is what the running sim does with it, step after step, and so
it lives with the sim (physics.py's Simulation is its one user in the
product; the robot tests and benchmarks drive it directly). No network here.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from zensim.robots.builder import Robot, place_base, spawn_pose

def _vector(robot: Robot, name: str, value: object) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (robot.nu,):
        raise ValueError(f"{name} must have {robot.nu} values (one per joint), got {arr.shape[0]}")
    return arr


def apply_motor_command(robot: Robot, data: mujoco.MjData, q: object, dq: object, kp: object, kd: object,
                        tau: object) -> None:
    """Set the motor command for the next steps (Unitree LowCmd semantics), in canonical joint order.

    tau_joint = kp*(q - q_meas) + kd*(dq - dq_meas) + tau, clipped to the URDF effort limit. The gains go
    into the model's affine bias (so MuJoCo integrates the kd term implicitly) and the rest into ctrl.
    The gains live in `robot.model`: every MjData of this model shares them.

    Raises:
        ValueError: An argument does not have one value per joint.
    """
    q_, dq_, kp_, kd_, tau_ = (_vector(robot, n, v) for n, v in
                               (("q", q), ("dq", dq), ("kp", kp), ("kd", kd), ("tau", tau)))
    write_actuators(robot, data, robot.actuator_ids, *actuator_values(q_, dq_, kp_, kd_, tau_))


def actuator_values(q: np.ndarray, dq: np.ndarray, kp: np.ndarray, kd: np.ndarray,
                    tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A motor command as the actuators take it: the bias's -kp and -kd, and ctrl = kp*q + kd*dq + tau."""
    return -kp, -kd, kp * q + kd * dq + tau


def write_actuators(robot: Robot, data: mujoco.MjData, index: np.ndarray | slice, neg_kp: np.ndarray,
                    neg_kd: np.ndarray, ctrl: np.ndarray) -> None:
    """Write actuator_values into the model's bias and `data.ctrl` (`index`: the robot's actuators, as
    `actuator_index` gives them)."""
    robot.model.actuator_biasprm[index, 1] = neg_kp
    robot.model.actuator_biasprm[index, 2] = neg_kd
    data.ctrl[index] = ctrl


def actuator_index(robot: Robot) -> np.ndarray | slice:
    """The robot's actuators in canonical joint order: a slice when they are consecutive (they are when the
    builder made the model: a slice writes several times faster than a list of ids), else their ids."""
    ids = robot.actuator_ids
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


def reset(robot: Robot, data: mujoco.MjData, q: np.ndarray | None = None, base_height_m: float | None = None) -> None:
    """Reset to a pose held by the default gains, then mj_forward so sensors are current.

    Args:
        robot: The robot.
        data: Its MjData.
        q: Joint positions (canonical order); default: `robot.default_q`.
        base_height_m: Base height; default: `robot.base_height_m`. In the fixed mode this moves the
            weld, which is part of the model.
    """
    q_ = robot.default_q.copy() if q is None else _vector(robot, "q", q)
    height = robot.base_height_m if base_height_m is None else float(base_height_m)
    if robot.slot is None:
        mujoco.mj_resetData(robot.model, data)
    else:
        _reset_slot(robot, data)
    place_base(robot, height)
    if robot.free_qpos_adr >= 0:
        a = robot.free_qpos_adr
        data.qpos[a:a + 7] = spawn_pose(robot, height)
    data.qpos[robot.qpos_adr] = q_
    zeros = np.zeros(robot.nu)
    apply_motor_command(robot, data, q_, zeros, robot.kp, robot.kd, zeros)
    if robot.slot is None:
        mujoco.mj_forward(robot.model, data)
        return
    # In a world, mj_forward would also recompute the other robots' acceleration-stage figures (actuator
    # torques, accelerometers) of this instant: they keep what they last published; only this robot moved.
    torques, sensors = data.qfrc_actuator.copy(), data.sensordata.copy()
    mujoco.mj_forward(robot.model, data)
    own_dof = robot.slot.dof
    torques[own_dof] = data.qfrc_actuator[own_dof]
    for own in robot.sensor_slices.values():
        sensors[own] = data.sensordata[own]
    data.qfrc_actuator[:] = torques
    data.sensordata[:] = sensors


def _reset_slot(robot: Robot, data: mujoco.MjData) -> None:
    """mj_resetData for one robot of a world: its own state only; time and the other robots go on."""
    slot, model = robot.slot, robot.model
    assert slot is not None
    data.qpos[slot.qpos] = model.qpos0[slot.qpos]
    for array in (data.qvel, data.qacc, data.qacc_warmstart, data.qfrc_applied):
        array[slot.dof] = 0.0
    data.xfrc_applied[slot.bodies] = 0.0
    data.ctrl[slot.actuators] = 0.0


def _rotate_to_body(quat_wxyz: np.ndarray, vec_world: np.ndarray) -> np.ndarray:
    conj = np.array([quat_wxyz[0], -quat_wxyz[1], -quat_wxyz[2], -quat_wxyz[3]])
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, vec_world, conj)
    return out


def read_base(robot: Robot, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Base link frame (XBODY, not the centre of mass) state from sensors.

    Sensors are computed before integration: call mj_forward after mj_step for current values.

    Returns:
        pos (3, world, m), quat_wxyz (4), lin_vel_world (3, m/s), ang_vel_body (3, rad/s).
    """
    s = data.sensordata
    quat = s[robot.sensor_slices["base_quat"]].copy()
    ang_world = s[robot.sensor_slices["base_angvel"]]
    return (s[robot.sensor_slices["base_pos"]].copy(), quat, s[robot.sensor_slices["base_linvel"]].copy(),
            _rotate_to_body(quat, ang_world))


def read_imu(robot: Robot, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU readings from the site at the IMU link.

    Returns:
        quat_wxyz (4, world from IMU), gyro_body (3, rad/s), accel_body (3, m/s^2, includes -gravity
        as a real accelerometer does: +9.81 up when at rest).
    """
    s = data.sensordata
    return (s[robot.sensor_slices["imu_quat"]].copy(), s[robot.sensor_slices["imu_gyro"]].copy(),
            s[robot.sensor_slices["imu_accel"]].copy())


def base_tilt_rad(robot: Robot, data: mujoco.MjData) -> float:
    """Angle between the base's z axis and the world's z axis, rad (0 upright, pi upside down)."""
    w, x, y, z = data.sensordata[robot.sensor_slices["base_quat"]]
    norm2 = w * w + x * x + y * y + z * z
    cos_tilt = 1.0 - 2.0 * (x * x + y * y) / norm2
    return float(math.acos(max(-1.0, min(1.0, cos_tilt))))


def warnings_of(data: mujoco.MjData) -> dict[str, int]:
    """MuJoCo runtime warnings raised so far, by name (empty when the run was clean)."""
    return {mujoco.mjtWarning(i).name: int(data.warning[i].number)
            for i in range(len(data.warning)) if data.warning[i].number}
