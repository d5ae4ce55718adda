"""Robot descriptions, control config and the MuJoCo builder, on real MuJoCo (no mocks).

The official G1 checks run when ZENSIM_OFFICIAL_G1 names a g1_description folder (see conftest).
Bounds below are measured figures with margin; docs/robots.md has the measurements.
"""

from __future__ import annotations

import fnmatch
import re
import struct
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yourdfpy

from zensim.robots import BUNDLED_DIR, bundled_robots, robot_files
from zensim.robots.builder import Robot, build
from zensim.robots.cli import main as cli_main
from zensim.robots.control import ControlConfigError, load_control, unmatched_patterns
from zensim.robots.description import parse_urdf
from zensim.robots.unitree_g1.derive import read_stl
from zensim.sim.mjdata import apply_motor_command, base_tilt_rad, read_base, read_imu, reset, warnings_of

# Standing in the squat, 30 s, default gains (measured: settled pelvis 0.7249-0.7255 m, tilt <= 0.011
# rad after the 12 cm drop; min 0.7056 m and tilt 0.024 rad during the drop's first second).
STAND_S = 30.0
SETTLE_S = 2.0
HEIGHT_BOUNDS_M = (0.69, 0.86)
SETTLED_HEIGHT_BOUNDS_M = (0.715, 0.735)
MAX_TILT_RAD = 0.05
SETTLED_MAX_TILT_RAD = 0.02
# Fixed mode: every joint within this of a step target 5 s later (measured: settled < 0.01 rad by 3.5 s).
TRACK_AFTER_S = 5.0
TRACK_TOL_RAD = 0.01

SMALL_ARM = """<robot name="small_arm">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="upper"><inertial><origin xyz="0 0 0.15"/><mass value="0.5"/><inertia ixx="0.004" iyy="0.004" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <link name="fore"><inertial><origin xyz="0 0 0.1"/><mass value="0.3"/><inertia ixx="0.001" iyy="0.001" izz="0.0002" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.02" length="0.2"/></geometry></collision></link>
  <link name="tip"><inertial><mass value="0.05"/><inertia ixx="1e-5" iyy="1e-5" izz="1e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><sphere radius="0.02"/></geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="20" velocity="5"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="0.2" upper="2.0" effort="10" velocity="5"/></joint>
  <joint name="wrist" type="continuous"><parent link="fore"/><child link="tip"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/></joint>
</robot>
"""


@pytest.fixture
def mujoco_messages() -> Iterator[list[str]]:
    """Collect mju_warning messages (compile and runtime) that MuJoCo would otherwise only print."""
    messages: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(messages.append)
    yield messages
    mujoco.set_mju_user_warning(previous)


@pytest.fixture(scope="module")
def ours() -> Path:
    return robot_files("g1").urdf


def _g1_variants(official_dir: Path | None) -> dict[str, Path]:
    variants = {"ours": robot_files("g1").urdf}
    if official_dir is not None:
        variants["official"] = official_dir / "g1_29dof.urdf"
    return variants


def _step(robot: Robot, data: mujoco.MjData, seconds: float) -> None:
    for _ in range(round(seconds / robot.model.opt.timestep)):
        mujoco.mj_step(robot.model, data)


def _stand(robot: Robot) -> dict[str, float]:
    """Run the default pose for STAND_S and return the pelvis height and tilt extremes."""
    data = mujoco.MjData(robot.model)
    reset(robot, data)
    heights, tilts = [], []
    for i in range(round(STAND_S / robot.model.opt.timestep)):
        mujoco.mj_step(robot.model, data)
        if i % 10 == 0:
            mujoco.mj_forward(robot.model, data)
            heights.append((data.time, read_base(robot, data)[0][2]))
            tilts.append((data.time, base_tilt_rad(robot, data)))
    assert warnings_of(data) == {}
    h, t = np.array(heights), np.array(tilts)
    late = h[:, 0] > SETTLE_S
    return {"h_min": h[:, 1].min(), "h_max": h[:, 1].max(), "tilt_max": t[:, 1].max(),
            "late_h_min": h[late, 1].min(), "late_h_max": h[late, 1].max(), "late_tilt_max": t[late, 1].max()}


def _check_compiles_and_steps(files, mode: str, messages: list[str], capfd: pytest.CaptureFixture[str]) -> Robot:
    robot = build(files, mode)  # type: ignore[arg-type]
    data = mujoco.MjData(robot.model)
    reset(robot, data)
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(robot.q_min), robot.q_min, -np.pi)
    hi = np.where(np.isfinite(robot.q_max), robot.q_max, np.pi)
    for _ in range(5):  # bounded pseudo-random targets, as mujoco_menagerie's model test does
        target = np.clip(robot.default_q + rng.uniform(-0.2, 0.2, robot.nu), lo, hi)
        apply_motor_command(robot, data, target, np.zeros(robot.nu), robot.kp, robot.kd, np.zeros(robot.nu))
        _step(robot, data, 0.2)
    assert warnings_of(data) == {}
    assert messages == []
    assert capfd.readouterr().err == ""
    assert np.isfinite(data.qpos).all()
    return robot


class TestCompile:
    @pytest.mark.parametrize("mode", ["floating", "fixed"])
    def test_our_g1(self, mode: str, mujoco_messages: list[str], capfd: pytest.CaptureFixture[str]) -> None:
        robot = _check_compiles_and_steps(robot_files("g1"), mode, mujoco_messages, capfd)
        assert robot.nu == 29 and len(robot.mesh_files) == 36  # the visual shells, served to viewers
        assert robot.model.nmesh == 0  # collisions are primitives: MuJoCo compiles no mesh
        assert robot.model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        assert (robot.model.opt.gravity[2] < 0) == (mode == "floating")

    @pytest.mark.parametrize("mode", ["floating", "fixed"])
    @pytest.mark.parametrize("with_g1_control", [False, True])
    def test_official_g1(self, official_g1_dir: Path, mode: str, with_g1_control: bool,
                         mujoco_messages: list[str], capfd: pytest.CaptureFixture[str]) -> None:
        urdf = official_g1_dir / "g1_29dof.urdf"
        files = robot_files("g1", urdf=urdf) if with_g1_control else robot_files(urdf=urdf)
        robot = _check_compiles_and_steps(files, mode, mujoco_messages, capfd)
        assert len(robot.mesh_files) == 36
        assert all(p.is_file() and p.is_relative_to(official_g1_dir.resolve()) for p in robot.mesh_files.values())

    @pytest.mark.parametrize("mode", ["floating", "fixed"])
    def test_small_arm_with_defaults(self, tmp_path: Path, mode: str, mujoco_messages: list[str],
                                     capfd: pytest.CaptureFixture[str]) -> None:
        (tmp_path / "arm.urdf").write_text(SMALL_ARM)
        files = robot_files(urdf=tmp_path / "arm.urdf")
        assert files.control is None
        robot = _check_compiles_and_steps(files, mode, mujoco_messages, capfd)
        assert robot.joint_names == ("shoulder", "elbow", "wrist")
        assert robot.default_q.tolist() == [0.0, 0.2, 0.0]  # zero pose clipped into the elbow's limits
        assert np.isinf(robot.q_max[2]) and np.isinf(robot.effort_limit[2])
        np.testing.assert_allclose(robot.kp, [40.0, 20.0, 100.0])  # 2 * effort; no effort -> 100
        # Spawn/fixed height from the lowest point: the base box bottom just above the floor.
        assert robot.base_height_m == pytest.approx(0.002, abs=1e-6)


class TestFolders:
    @pytest.mark.parametrize("name", bundled_robots())
    def test_folder_has_required_files(self, name: str) -> None:
        folder = BUNDLED_DIR / name
        for required in ("README.md", "LICENSE", "CHANGELOG.md", "control.toml"):
            assert (folder / required).is_file(), required
        assert list(folder.glob("*.urdf"))

    @pytest.mark.parametrize("name", bundled_robots())
    @pytest.mark.parametrize("mode", ["floating", "fixed"])
    def test_control_patterns_match_urdf_and_mujoco_joints(self, name: str, mode: str) -> None:
        files = robot_files(name)
        urdf = yourdfpy.URDF.load(str(files.urdf), load_meshes=False, build_scene_graph=False)
        actuated = [j.name for j in urdf.robot.joints if j.type in ("revolute", "continuous", "prismatic")]
        robot = build(files, mode)  # type: ignore[arg-type]
        model = robot.model
        mj_joints = [model.joint(i).name for i in range(model.njnt) if model.jnt_type[i] != mujoco.mjtJoint.mjJNT_FREE]
        assert list(robot.joint_names) == actuated == mj_joints
        assert unmatched_patterns(robot.control, actuated) == []
        # Every joint gets its gains from a group, not from the no-control fallback.
        for gains in (robot.control.floating.gains, robot.control.fixed.gains):
            assert all(any(fnmatch.fnmatchcase(n, p) for g in gains for p in g.joints) for n in actuated)

    def test_floors_leave_g1_masses_alone(self) -> None:
        robot = build(robot_files("g1"), "floating")
        urdf = yourdfpy.URDF.load(str(robot.urdf_path), load_meshes=False, build_scene_graph=False)
        for link in urdf.robot.links:
            if link.inertial is not None:
                assert robot.model.body(link.name).mass[0] == pytest.approx(link.inertial.mass)
        assert robot.model.body_subtreemass[0] == pytest.approx(35.11214, abs=1e-4)

    def test_our_g1_figures_equal_the_official(self, official_g1_dir: Path) -> None:
        load = lambda p: yourdfpy.URDF.load(str(p), load_meshes=False, build_scene_graph=False).robot  # noqa: E731
        ours, official = load(robot_files("g1").urdf), load(official_g1_dir / "g1_29dof.urdf")
        off_joints = {j.name: j for j in official.joints}
        kept = [j.name for j in ours.joints]
        assert [j for j in off_joints if j not in kept] == ["pelvis_contour_joint", "logo_joint", "waist_support_joint"]
        for j in ours.joints:
            o = off_joints[j.name]
            assert (j.type, j.parent, j.child) == (o.type, o.parent, o.child)
            np.testing.assert_allclose(j.origin, o.origin, atol=1e-12)
            if j.type != "fixed":
                np.testing.assert_allclose(j.axis, o.axis)
                assert (j.limit.lower, j.limit.upper, j.limit.effort, j.limit.velocity) == (
                    o.limit.lower, o.limit.upper, o.limit.effort, o.limit.velocity)
        off_links = {link.name: link for link in official.links}
        for link in ours.links:
            o = off_links[link.name]
            if o.inertial is None:
                assert link.inertial is None
                continue
            assert link.inertial.mass == o.inertial.mass
            np.testing.assert_allclose(link.inertial.origin, o.inertial.origin)
            np.testing.assert_allclose(link.inertial.inertia, o.inertial.inertia)


def _model_bytes(model: mujoco.MjModel) -> bytes:
    buffer = np.empty(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


class TestVisualMeshes:
    """The bundled G1 draws Unitree's own (decimated) shells; its physics is the primitives' alone."""

    def test_every_link_is_drawn_with_a_shipped_mesh(self) -> None:
        files = robot_files("g1")
        description = parse_urdf(files.urdf.read_text())
        drawn = {link for link, visuals in description.visuals.items() if any(v.kind == "mesh" for v in visuals)}
        assert drawn == {link for link in description.links if description.visuals.get(link)}
        # Every moving link and the pelvis carry a shell; sensor frames carry none.
        assert {j.child for j in description.actuated_joints} | {"pelvis", "head_link"} <= drawn
        for filename in {v.filename for vs in description.visuals.values() for v in vs}:
            path = files.urdf.parent / filename
            assert path.is_file(), filename
            (count,) = struct.unpack_from("<I", path.read_bytes(), 80)
            assert path.stat().st_size == 84 + 50 * count > 84, filename  # a binary STL with triangles

    @pytest.mark.parametrize("mode", ["floating", "fixed"])
    def test_the_visuals_leave_the_physics_bit_identical(self, tmp_path: Path, mode: str) -> None:
        """The same URDF with every <visual> removed compiles to the same model and the same motion."""
        files = robot_files("g1")
        text = files.urdf.read_text()
        assert text.count('<mesh filename="meshes/') >= 30
        stripped = tmp_path / "g1_29dof.urdf"
        stripped.write_text(re.sub(r"\s*<visual>.*?</visual>", "", text, flags=re.S))
        assert "<visual>" not in stripped.read_text()
        with_visuals = build(files, mode)  # type: ignore[arg-type]
        without = build(robot_files("g1", urdf=stripped), mode)  # type: ignore[arg-type]
        assert with_visuals.model.nmesh == 0  # MuJoCo loads no visual mesh: nothing to compile
        # MuJoCo colours a link's collision geoms with its visual's material: the one field a
        # renderer alone reads. Everything else, byte for byte.
        without.model.geom_rgba[:] = with_visuals.model.geom_rgba
        assert _model_bytes(with_visuals.model) == _model_bytes(without.model)
        runs = []
        for robot in (with_visuals, without):
            data = mujoco.MjData(robot.model)
            reset(robot, data)
            _step(robot, data, 2.0)
            runs.append(np.concatenate([data.qpos, data.qvel, data.qfrc_actuator]))
        assert np.array_equal(runs[0], runs[1])

    def test_decimated_meshes_keep_the_official_shape(self, official_g1_dir: Path) -> None:
        """Each shipped mesh fills the official mesh's bounding box to within 2 mm on every side."""
        ours = robot_files("g1").urdf.parent / "meshes"
        for path in sorted(ours.glob("*.STL")):
            official = official_g1_dir / "meshes" / path.name
            mine, theirs = read_stl(path), read_stl(official)
            np.testing.assert_allclose(mine.min(axis=0), theirs.min(axis=0), atol=0.002, err_msg=path.name)
            np.testing.assert_allclose(mine.max(axis=0), theirs.max(axis=0), atol=0.002, err_msg=path.name)
            assert len(mine) < len(theirs), path.name


class TestStanding:
    def _check(self, figures: dict[str, float]) -> None:
        assert HEIGHT_BOUNDS_M[0] < figures["h_min"] and figures["h_max"] < HEIGHT_BOUNDS_M[1], figures
        assert SETTLED_HEIGHT_BOUNDS_M[0] < figures["late_h_min"], figures
        assert figures["late_h_max"] < SETTLED_HEIGHT_BOUNDS_M[1], figures
        assert figures["tilt_max"] < MAX_TILT_RAD and figures["late_tilt_max"] < SETTLED_MAX_TILT_RAD, figures

    def test_our_g1_stands_30s(self) -> None:
        self._check(_stand(build(robot_files("g1"), "floating")))

    def test_official_g1_stands_30s(self, official_g1_dir: Path) -> None:
        self._check(_stand(build(robot_files("g1", urdf=official_g1_dir / "g1_29dof.urdf"), "floating")))

    def test_sensors_at_rest(self) -> None:
        robot = build(robot_files("g1"), "floating")
        data = mujoco.MjData(robot.model)
        reset(robot, data)
        _step(robot, data, 2.0)
        mujoco.mj_forward(robot.model, data)
        pos, quat, lin_vel, ang_vel = read_base(robot, data)
        np.testing.assert_allclose(pos, data.xpos[robot.base_body_id])
        np.testing.assert_allclose(quat, data.xquat[robot.base_body_id])
        assert np.abs(lin_vel).max() < 0.01 and np.abs(ang_vel).max() < 0.01
        imu_quat, gyro, accel = read_imu(robot, data)
        np.testing.assert_allclose(imu_quat, quat, atol=1e-9)  # the IMU frame is aligned with the pelvis
        np.testing.assert_allclose(gyro, ang_vel, atol=1e-9)  # same rigid body, same axes
        assert accel[2] == pytest.approx(9.81, abs=0.05)


class TestFixedMode:
    def test_tracks_targets(self) -> None:
        robot = build(robot_files("g1"), "fixed")
        data = mujoco.MjData(robot.model)
        for seed in range(3):
            reset(robot, data)
            target = robot.q_min + (robot.q_max - robot.q_min) * np.random.default_rng(seed).uniform(0.3, 0.7, robot.nu)
            apply_motor_command(robot, data, target, np.zeros(robot.nu), robot.kp, robot.kd, np.zeros(robot.nu))
            _step(robot, data, TRACK_AFTER_S)
            error = np.abs(data.qpos[robot.qpos_adr] - target)
            assert error.max() < TRACK_TOL_RAD, dict(zip(robot.joint_names, error.round(4)))
            np.testing.assert_allclose(data.xpos[robot.base_body_id], [0, 0, 0.79])
        assert warnings_of(data) == {}

    @pytest.mark.parametrize("which", ["ours", "official"])
    def test_every_joint_sweeps_its_whole_range_without_touching_the_floor(self, which: str, request) -> None:
        """The SDK examples' first move, a ramp to the zero pose, then each joint through its full range.

        Welded at 0.79 m, the straight legs reach 2.3 mm below the base height's floor: before the
        fixed mode stopped colliding with the floor, the zero pose pressed the feet in with 8 contacts
        and the ankles swung through 22 % of their amplitude.
        """
        urdf = None if which == "ours" else request.getfixturevalue("official_g1_dir") / "g1_29dof.urdf"
        robot = build(robot_files("g1", urdf=urdf), "fixed")
        model, data = robot.model, mujoco.MjData(robot.model)
        floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        reset(robot, data)
        zeros = np.zeros(robot.nu)
        touches: list[tuple[str, float]] = []

        def follow(path: np.ndarray, seconds: float, moving: str) -> None:
            """Ramp the targets along `path` (rows of joint targets) over `seconds`, then hold 1 s."""
            steps = round(seconds / model.opt.timestep)
            for i in range(steps + round(1.0 / model.opt.timestep)):
                s = min(i / steps, 1.0) * (len(path) - 1)
                k = min(int(s), len(path) - 2)
                target = path[k] + (s - k) * (path[k + 1] - path[k])
                apply_motor_command(robot, data, target, zeros, robot.kp, robot.kd, zeros)
                mujoco.mj_step(model, data)
                contacts = data.contact[:data.ncon]
                if np.any((contacts.geom1 == floor) | (contacts.geom2 == floor)):
                    touches.append((moving, data.time))

        follow(np.array([data.qpos[robot.qpos_adr], zeros]), 2.0, "ramp to zero")
        np.testing.assert_allclose(data.qpos[robot.qpos_adr], 0.0, atol=0.01)
        for j, name in enumerate(robot.joint_names):
            lo, hi = zeros.copy(), zeros.copy()
            lo[j], hi[j] = robot.q_min[j], robot.q_max[j]
            reached = []
            for path in (np.array([zeros, lo]), np.array([lo, hi]), np.array([hi, zeros])):
                follow(path, 1.0, name)
                reached.append(data.qpos[robot.qpos_adr[j]])
            # The sweep is real: the joint got to both ends of its range (kp 50, no gravity, no floor).
            assert reached[0] == pytest.approx(robot.q_min[j], abs=0.02), name
            assert reached[1] == pytest.approx(robot.q_max[j], abs=0.02), name
        assert touches == [], f"floor contacts while welded: first {touches[:3]}, {len(touches)} steps in all"
        np.testing.assert_allclose(data.xpos[robot.base_body_id], [0, 0, 0.79])
        assert warnings_of(data) == {}

    def test_command_length_is_checked(self) -> None:
        robot = build(robot_files("g1"), "fixed")
        data = mujoco.MjData(robot.model)
        with pytest.raises(ValueError, match="29 values"):
            apply_motor_command(robot, data, np.zeros(3), np.zeros(29), robot.kp, robot.kd, np.zeros(29))


class TestControlFile:
    @pytest.mark.parametrize(("text", "field"), [
        ("[model]\ntimestep_s = 0.002\nbogus = 1\n", "bogus"),
        ("[[floating.gains]]\njoints = ['*']\nkp = 'stiff'\nkd = 1.0\n", "$.floating.gains[0].kp"),
        ("[model]\nintegrator = 'verlet'\n", "$.model.integrator"),
        ("[fixed]\nbase_height_m = -1.0\n", "$.fixed.base_height_m"),
    ])
    def test_bad_file_names_the_field(self, tmp_path: Path, text: str, field: str) -> None:
        path = tmp_path / "control.toml"
        path.write_text(text)
        with pytest.raises(ControlConfigError) as info:
            load_control(path)
        assert field in str(info.value) and str(path) in str(info.value)

    def test_bad_file_fails_build(self, tmp_path: Path) -> None:
        (tmp_path / "control.toml").write_text("[floating]\nheight = 1\n")
        with pytest.raises(ControlConfigError, match="height"):
            build(robot_files("g1", control=tmp_path / "control.toml"), "floating")

    def test_an_explicit_zero_armature_is_kept(self, tmp_path: Path) -> None:
        bundled = robot_files("g1").control.read_text()
        (tmp_path / "control.toml").write_text(bundled.replace("value = 0.025", "value = 0.0", 1))
        robot = build(robot_files("g1", control=tmp_path / "control.toml"), "fixed")
        knee = robot.model.joint("left_knee_joint").dofadr[0]
        hip_pitch = robot.model.joint("left_hip_pitch_joint").dofadr[0]
        assert robot.model.dof_armature[knee] == 0.0, "an explicit armature of 0 became the default"
        assert robot.model.dof_armature[hip_pitch] == pytest.approx(0.01)

    def test_robot_files(self) -> None:
        assert robot_files() == robot_files("g1") == robot_files("unitree_g1")
        with pytest.raises(FileNotFoundError, match="unknown robot"):
            robot_files("atlas")


class TestCli:
    def test_build_and_info(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        assert cli_main(["build", "g1", "--mode", "fixed", "-o", str(tmp_path)]) == 0
        xml = tmp_path / "g1_29dof_fixed.xml"
        model = mujoco.MjModel.from_xml_path(str(xml))
        assert model.nu == 29 and model.opt.gravity[2] == 0
        assert "kp = 50.0" in (tmp_path / "g1_29dof_fixed_control.toml").read_text()
        assert cli_main(["info", "g1"]) == 0
        assert "left_knee_joint" in capsys.readouterr().out
        assert cli_main(["info", "--urdf", str(tmp_path / "missing.urdf")]) == 2
