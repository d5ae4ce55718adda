"""Terrain generated into the MuJoCo model: heights where the spec puts them (MuJoCo's own ray casts), things
dropped on it resting where they should, the same seed giving the same ground, the G1 spawning on it, and
absurd terrain files refused whole with one line. Real MuJoCo, no processes (test_terrain_process.py has those)."""

from __future__ import annotations

import math
import warnings
from typing import Any
from pathlib import Path

import msgspec
import mujoco
import numpy as np
import pytest

from zensim.robots import robot_files
from zensim.robots.builder import FLOOR_BIT, ROBOT_BIT, Placement, build, build_world
from zensim.robots import terrain as terrain_module
from zensim.robots.terrain import TerrainError, add_to_spec, ground_at, load_terrain, rough_heights, terrain_from_table
from zensim.schemas import Codec, RobotInfo
from zensim.schemas.messages import RoughGround, Terrain
from zensim.sim.physics import Limits, Simulation
from zensim.sim.world import World

TAN10 = math.tan(math.radians(10))
COURSE: dict[str, Any] = {"features": [
    {"type": "slope", "angle_deg": 10, "length_m": 3, "width_m": 2, "top_m": 1, "at": [2, 0]},
    {"type": "stairs", "step_height_m": 0.12, "step_depth_m": 0.3, "count": 4, "at": [0, 3], "direction_deg": 90},
    {"type": "stairs", "step_height_m": 0.1, "step_depth_m": 0.25, "count": 3, "way": "down", "landing_m": 0.5,
     "at": [0, -3], "direction_deg": -90},
    {"type": "rough", "size_m": [2, 1.5], "amplitude_m": 0.05, "cell_m": 0.1, "seed": 7, "at": [-3, 0]},
    {"type": "stones", "rows": 3, "columns": 2, "stone_m": 0.3, "gap_m": 0.1, "height_m": 0.15, "at": [6, 3]},
    {"type": "box", "size_m": [1, 0.5, 0.2], "pos": [6, -3, 0.1], "rpy_deg": [0, 0, 90]},
]}


@pytest.fixture(scope="module")
def course() -> tuple[Terrain, mujoco.MjModel, mujoco.MjData]:
    terrain = terrain_from_table(COURSE)
    robot = build(robot_files("g1"), "floating", terrain)
    data = mujoco.MjData(robot.model)
    mujoco.mj_forward(robot.model, data)
    return terrain, robot.model, data


def heights(model: mujoco.MjModel, data: mujoco.MjData, points: list[tuple[float, float]]) -> np.ndarray:
    return np.array([ground_at(model, data, x, y) for x, y in points])


class TestHeights:
    """MuJoCo's own ray casts (mj_ray) at points sampled over each feature, against the spec's figures."""

    def test_slope_rises_at_its_angle_then_holds_its_top(self, course) -> None:
        _, model, data = course
        s = np.linspace(0.05, 2.95, 15)
        got = heights(model, data, [(2 + si, y) for si in s for y in (-0.9, 0.0, 0.9)]).reshape(-1, 3)
        np.testing.assert_allclose(got, np.repeat((s * TAN10)[:, None], 3, axis=1), atol=1e-6)
        top = heights(model, data, [(5.2, 0.0), (5.9, 0.5)])
        np.testing.assert_allclose(top, 3 * TAN10, atol=1e-6)
        assert heights(model, data, [(1.9, 0.0), (6.1, 0.0), (3.0, 1.1)]).max() == 0.0, "the slope spills over its edges"

    def test_stairs_up_and_down_have_their_steps(self, course) -> None:
        _, model, data = course
        # Up along +y from y = 3: step k (0-based) 0.12 (k + 1) high for 0.3 m; the last runs on as the landing.
        ys = [3 + 0.3 * k + 0.15 for k in range(4)] + [3 + 1.2 + 0.9]
        np.testing.assert_allclose(heights(model, data, [(0.5, y) for y in ys]), [0.12, 0.24, 0.36, 0.48, 0.48], atol=1e-6)
        assert heights(model, data, [(0.0, 2.95), (0.0, 3 + 1.2 + 1.0 + 0.05), (1.05, 3.5)]).max() == 0.0
        # Down along -y from y = -3: the landing (0.5 m plus one tread) 0.3 high, then 0.2, 0.1, then the floor.
        ys = [-3 - 0.2, -3 - 0.7, -3 - 0.75 - 0.125, -3 - 1.0 - 0.125, -3 - 1.25 - 0.1]
        np.testing.assert_allclose(heights(model, data, [(-0.3, y) for y in ys]), [0.3, 0.3, 0.2, 0.1, 0.0], atol=1e-6)

    def test_stepping_stones_stand_with_gaps_between(self, course) -> None:
        _, model, data = course
        # Rows along +x from x = 6, two columns centred on y = 3: stones over y in [2.65, 2.95] and [3.05, 3.35].
        tops = [(6 + 0.15 + 0.4 * row, y) for row in range(3) for y in (2.8, 3.2)]
        np.testing.assert_allclose(heights(model, data, tops), 0.15, atol=1e-6)
        gaps = [(6.15, 3.0), (6.35, 2.8), (6.75, 3.2), (7.25, 2.8), (6.15, 3.4)]
        assert heights(model, data, gaps).max() == 0.0

    def test_a_box_stands_at_its_pose(self, course) -> None:
        _, model, data = course
        # 1 x 0.5 footprint turned 90 degrees: 0.5 along x, 1 along y.
        np.testing.assert_allclose(heights(model, data, [(6.2, -3.45), (5.8, -2.55), (6.0, -3.0)]), 0.2, atol=1e-6)
        assert heights(model, data, [(6.3, -3.0), (6.0, -3.55)]).max() == 0.0

    def test_rough_ground_matches_its_seeded_grid(self, course) -> None:
        terrain, model, data = course
        rough = terrain.features[3]
        assert isinstance(rough, RoughGround)
        grid = rough_heights(rough)
        assert grid.shape == (16, 21)  # 1.5 m by 2 m at 0.1 m: 15 x 20 cells
        assert 0.0 <= grid.min() and grid.max() <= 0.05 and grid.max() > 0.04
        assert not grid[[0, -1], :].any() and not grid[:, [0, -1]].any(), "the border is not at floor level"
        rows, cols = np.meshgrid(np.arange(1, 15, 3), np.arange(1, 20, 3), indexing="ij")
        points = [(float(-4 + 0.1 * c), float(-0.75 + 0.1 * r)) for r, c in zip(rows.ravel(), cols.ravel())]
        np.testing.assert_allclose(heights(model, data, points), grid[rows.ravel(), cols.ravel()], atol=1e-6)
        # Between grid points MuJoCo's triangles interpolate: midway along x, the mean of the two neighbours.
        np.testing.assert_allclose(ground_at(model, data, -4 + 0.55, -0.75 + 0.5), (grid[5, 5] + grid[5, 6]) / 2,
                                   atol=1e-6)

    def test_same_seed_same_ground_other_seed_other_ground(self) -> None:
        def field(seed: int) -> np.ndarray:
            terrain = terrain_from_table({"features": [dict(COURSE["features"][3], seed=seed)]})
            robot = build(robot_files("g1"), "floating", terrain)
            return robot.model.hfield_data.copy()

        first, again, other = field(7), field(7), field(8)
        assert np.array_equal(first, again)
        assert not np.allclose(first, other)
        # Pinned figures: a hash (splitmix64), not a library's generator, makes the ground, so the same seed
        # gives the same ground on every machine and numpy version; a change to it shows here.
        grid = rough_heights(RoughGround(size_m=(1.0, 1.0), amplitude_m=1.0, cell_m=0.5, seed=7))
        assert float(grid[1, 1]) == 0.5108909934968229
        grid = rough_heights(RoughGround(size_m=(1.5, 1.0), amplitude_m=1.0, cell_m=0.5, seed=2**63 - 1))
        assert [round(float(v), 8) for v in grid[1, 1:3]] == [0.18025973, 0.13619031]


def ground_model(terrain: Terrain) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The terrain alone in a model, as add_to_spec puts it in (kinematics done, for ray casts)."""
    spec = mujoco.MjSpec()
    add_to_spec(spec, terrain, FLOOR_BIT, FLOOR_BIT, [1.0, 0.005, 0.0001])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


class TestSlopeAsBlocks:
    """A slope whose top covers its tilted box's far end goes into the model as two boxes: the same ground as
    its prism (geometry(), what the viewer draws) everywhere above the floor, edges and crest included."""

    @pytest.mark.parametrize("slope", [
        {"angle_deg": 10, "length_m": 3, "width_m": 2, "top_m": 1, "at": [2, 0]},
        {"angle_deg": 3, "length_m": 3, "width_m": 3, "top_m": 1, "at": [0, -1.5], "direction_deg": 90},
        {"angle_deg": 30, "length_m": 1, "width_m": 1.5, "top_m": 0.34, "at": [-1, 2], "direction_deg": -143},
    ])
    def test_boxes_give_the_prisms_heights(self, slope: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
        terrain = terrain_from_table({"features": [{"type": "slope", **slope}]})
        boxes = ground_model(terrain)
        assert set(boxes[0].geom_type.tolist()) == {int(mujoco.mjtGeom.mjGEOM_BOX)}
        monkeypatch.setattr(terrain_module, "_slope_blocks", lambda f: None)
        prism = ground_model(terrain)
        assert set(prism[0].geom_type.tolist()) == {int(mujoco.mjtGeom.mjGEOM_MESH)}
        yaw, reach = math.radians(slope.get("direction_deg", 0)), slope["length_m"] + slope["top_m"]
        points = []
        for s in np.linspace(-0.2, reach + 0.2, 41):  # along the heading, past both ends
            for lateral in np.linspace(-slope["width_m"] / 2 - 0.1, slope["width_m"] / 2 + 0.1, 9):  # and its sides
                points.append((slope["at"][0] + s * math.cos(yaw) - lateral * math.sin(yaw),
                               slope["at"][1] + s * math.sin(yaw) + lateral * math.cos(yaw)))
        np.testing.assert_allclose(heights(*boxes, points), heights(*prism, points), atol=1e-6)
        assert heights(*boxes, points).max() == pytest.approx(slope["length_m"] * math.tan(math.radians(slope["angle_deg"])))

    def test_a_top_too_short_to_cover_the_far_end_keeps_the_prism(self) -> None:
        # 30 degrees over 1 m rises 0.577 m; the tilted box's far end leans 0.333 m out at the floor.
        terrain = terrain_from_table({"features": [{"type": "slope", "angle_deg": 30, "length_m": 1, "top_m": 0.3}]})
        assert ground_model(terrain)[0].geom_type.tolist() == [int(mujoco.mjtGeom.mjGEOM_MESH)]


def drop_box(terrain: Terrain, xy: tuple[float, float], half: float = 0.1, seconds: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """A free 20 cm cube dropped from 1 m above `xy` onto `terrain` (terrain.add_to_spec: as the sim builds it);
    its centre and its up axis (world frame) once it has come to rest."""
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.002
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], contype=FLOOR_BIT | ROBOT_BIT,
                            conaffinity=FLOOR_BIT | ROBOT_BIT)
    add_to_spec(spec, terrain, FLOOR_BIT | ROBOT_BIT, FLOOR_BIT | ROBOT_BIT, [1.0, 0.005, 0.0001])
    body = spec.worldbody.add_body(name="cube", pos=[xy[0], xy[1], 1.0])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[half] * 3, mass=1.0, friction=[1.0, 0.005, 0.0001])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=int(seconds / model.opt.timestep))
    assert np.linalg.norm(data.qvel[:3]) < 1e-3, "the box has not come to rest"
    return data.qpos[:3].copy(), data.body("cube").xmat.reshape(3, 3)[:, 2].copy()  # the terrain's bodies come first


class TestDroppedBox:
    def test_rests_on_a_slope_at_its_half_size_from_the_incline(self) -> None:
        terrain = terrain_from_table({"features": [{"type": "slope", "angle_deg": 10, "length_m": 3, "at": [0, 0]}]})
        centre, up = drop_box(terrain, (1.5, 0.0))
        # Distance from the centre to the incline's plane z = x tan(10 deg), along its normal: the half size.
        distance = (centre[2] - centre[0] * TAN10) * math.cos(math.radians(10))
        assert distance == pytest.approx(0.1, abs=2e-3)
        assert math.degrees(math.acos(up[2])) == pytest.approx(10, abs=0.5), "the box does not lie on the incline"
        assert 0.5 < centre[0] < 2.5, "the box slid off (friction 1 holds it on a 10 degree slope)"

    def test_rests_on_a_stair_at_its_tread(self) -> None:
        terrain = terrain_from_table({"features": [
            {"type": "stairs", "step_height_m": 0.15, "step_depth_m": 0.4, "count": 3, "at": [0, 0]}]})
        centre, up = drop_box(terrain, (0.6, 0.0))  # over the middle of the second step
        assert centre[2] == pytest.approx(0.3 + 0.1, abs=1e-3)
        assert up[2] == pytest.approx(1.0, abs=1e-4)

    def test_rests_on_the_floor_without_terrain_features(self) -> None:
        centre, _ = drop_box(Terrain(), (0.0, 0.0))  # the control: the rig itself puts a cube at its half size
        assert centre[2] == pytest.approx(0.1, abs=1e-3)


def standing(terrain: Terrain | None, seconds: float = 2.0) -> Simulation:
    """The G1 holding its default pose on `terrain` for `seconds`."""
    world = World.alone("g1", robot_files("g1"), "floating", Limits(max_kp=5000, max_kd=500), 0.5, terrain=terrain)
    (sim,) = world.robots
    sim.watchdog_enabled = False  # no commands: the default pose on its gains, as the watchdog would hold
    world.step(int(seconds / world.timestep_s))
    return sim


@pytest.fixture(scope="module")
def flat() -> Simulation:
    return standing(None)


class TestSpawn:
    """The floating G1 spawns over the highest ground under its feet (ray casts over its feet's footprint)."""

    def test_on_a_platform_it_spawns_raised_and_stands(self, flat: Simulation) -> None:
        platform = terrain_from_table({"features": [{"type": "box", "size_m": [1, 1, 0.3], "pos": [0, 0, 0.15]}]})
        sim = standing(platform)
        assert sim.robot.base_height_m == pytest.approx(flat.robot.base_height_m + 0.3, abs=1e-6)
        assert not sim.fallen()
        assert sim.data.qpos[2] == pytest.approx(flat.data.qpos[2] + 0.3, abs=0.01)

    def test_on_rough_ground_it_spawns_over_the_highest_bump_and_stands(self, flat: Simulation) -> None:
        terrain = terrain_from_table({"features": [
            {"type": "rough", "size_m": [2, 2], "amplitude_m": 0.01, "cell_m": 0.05, "seed": 3}]})
        sim = standing(terrain)
        lift = sim.robot.base_height_m - flat.robot.base_height_m
        assert 0.005 < lift <= 0.01, lift
        assert not sim.fallen()
        assert abs(sim.data.qpos[2] - flat.data.qpos[2]) < 0.015

    def test_beside_a_feature_it_spawns_as_on_the_flat(self, flat: Simulation) -> None:
        sim = standing(terrain_from_table(COURSE), seconds=0.5)
        assert sim.robot.base_height_m == flat.robot.base_height_m

    def test_a_world_robot_spawns_over_the_ground_at_its_own_place(self) -> None:
        terrain = terrain_from_table({"features": [{"type": "box", "size_m": [1, 1, 0.2], "pos": [3, 0, 0.1]}]})
        files = robot_files("g1")
        alone, raised = build_world([Placement("a/", files, (0.0, 0.0)), Placement("b/", files, (3.0, 0.0), 1.0)],
                                    "floating", terrain=terrain)
        assert raised.base_height_m == pytest.approx(alone.base_height_m + 0.2, abs=1e-6)

    def test_fixed_mode_keeps_its_stand_and_the_terrain_touches_nothing(self) -> None:
        """A robot on a stand touches neither the floor nor the terrain: MuJoCo leaves both out of the model."""
        terrain = terrain_from_table({"features": [{"type": "box", "size_m": [1, 1, 0.3], "pos": [0, 0, 0.15]}]})
        plain, on_terrain = build(robot_files("g1"), "fixed"), build(robot_files("g1"), "fixed", terrain)
        assert on_terrain.base_height_m == plain.base_height_m
        assert on_terrain.model.ngeom == plain.model.ngeom
        assert mujoco.mj_name2id(on_terrain.model, mujoco.mjtObj.mjOBJ_GEOM, "terrain_block_0") == -1


BAD = {
    "a 10^5 x 10^5 height field": ({"type": "rough", "size_m": [100, 100], "amplitude_m": 0.1, "cell_m": 0.001},
                                   "cell_m"),
    "a height field over the cell cap": ({"type": "rough", "size_m": [100, 100], "amplitude_m": 0.1, "cell_m": 0.05},
                                         "2000 x 2000 cells"),
    "NaN": ({"type": "slope", "angle_deg": float("nan"), "length_m": 3}, "angle_deg"),
    "infinity": ({"type": "box", "size_m": [1, 1, 1], "pos": [float("inf"), 0, 0]}, "pos"),
    "a negative size": ({"type": "box", "size_m": [1, -1, 1], "pos": [0, 0, 0]}, "size_m"),
    "a huge count": ({"type": "stairs", "step_height_m": 0.1, "step_depth_m": 0.3, "count": 10**6}, "count"),
    "a huge grid of stones": ({"type": "stones", "rows": 1000, "columns": 1000}, "4096"),
    "an absurd but finite place": ({"type": "box", "size_m": [1, 1, 1], "pos": [1e9, 0, 0]}, "pos"),
    "a slope rising a kilometre": ({"type": "slope", "angle_deg": 60, "length_m": 100}, "rises"),
    "a vertical slope": ({"type": "slope", "angle_deg": 90, "length_m": 1}, "angle_deg"),
    "an unknown type": ({"type": "lava", "size_m": [1, 1]}, "`type` must be one of"),
    "a type that is a list": ({"type": ["box"], "size_m": [1, 1, 1]}, "`type` must be one of"),
    "a misspelt key": ({"type": "slope", "angle_deg": 10, "length_m": 3, "widht_m": 2}, "widht_m"),
    "a wrong type": ({"type": "stairs", "step_height_m": "high", "step_depth_m": 0.3, "count": 3}, "step_height_m"),
}


class TestRefusals:
    @pytest.mark.parametrize("case", list(BAD))
    def test_bad_feature_refuses_the_whole_terrain_in_one_line(self, case: str) -> None:
        feature, said = BAD[case]
        good = {"type": "box", "size_m": [1, 1, 1], "pos": [0, 0, 0.5]}
        with pytest.raises(TerrainError) as caught:
            terrain_from_table({"features": [good, feature]})
        message = str(caught.value)
        assert said in message and "\n" not in message and len(message) < 300, message
        if case not in ("an unknown type", "a type that is a list", "a misspelt key", "a huge grid of stones"):
            assert "features[1]" in message, message  # says which feature

    def test_too_many_features_and_bad_shapes(self) -> None:
        box = {"type": "box", "size_m": [0.1, 0.1, 0.1], "pos": [0, 0, 0.05]}
        for table, said in [({"features": [box] * 65}, "at most 64"), ({"features": box}, "list"), ([box], "table"),
                            ({"features": [box], "seed": 3}, "'seed'"), ({"features": [3]}, "features[0]")]:
            with pytest.raises(TerrainError) as caught:
                terrain_from_table(table)
            assert said in str(caught.value), str(caught.value)

    def test_a_terrain_file_that_is_not_toml_too_big_or_missing(self, tmp_path: Path) -> None:
        path = tmp_path / "t.toml"
        path.write_text("[[features]\ntype = 'slope'")
        with pytest.raises(TerrainError, match="not TOML"):
            load_terrain(path)
        path.write_bytes(b"#" * (2 * 1024 * 1024))
        with pytest.raises(TerrainError, match="at most"):
            load_terrain(path)
        with pytest.raises(TerrainError, match="cannot read"):
            load_terrain(tmp_path / "missing.toml")
        path.write_text('[[features]]\ntype = "slope"\nangle_deg = 10\nlength_m = 3\n')
        assert load_terrain(path) == terrain_from_table({"features": [{"type": "slope", "angle_deg": 10, "length_m": 3}]})

    def test_a_hostile_description_on_the_wire_is_refused_like_a_file(self) -> None:
        """A replayed or spoofed info/robot carries the terrain too: the viewer decodes it with the same checks."""
        codec = Codec(RobotInfo)
        info = {"robot": "g1", "model": "m", "schema_version": 1, "joint_names": [], "q_min": [], "q_max": [],
                "effort_limit": [], "velocity_limit": [], "default_q": {}, "gains": {}, "base_height_m": {},
                "mode": "floating", "timestep_s": 0.002, "state_rate_hz": 100, "status_rate_hz": 10,
                "watchdog_timeout_s": 0.5}
        rough = {"type": "rough", "size_m": [100, 100], "amplitude_m": 0.1, "cell_m": 0.01}
        with pytest.raises(Exception, match="cells"):
            codec.decode(msgspec.json.encode(dict(info, terrain={"features": [rough]})))
        decoded = codec.decode(msgspec.json.encode(dict(info, terrain=COURSE)))
        assert decoded.terrain == terrain_from_table(COURSE)


class TestDrawing:
    """What the viewer sends the page for a terrain (services/viz/terrain.py): the shapes the model holds."""

    def test_every_shape_is_drawn_under_terrain_and_flat_only_clears_it(self) -> None:
        with warnings.catch_warnings():  # meshcat imports pyzmq's deprecated ioloop (warnings are errors here)
            warnings.simplefilter("ignore", DeprecationWarning)
            import umsgpack

            from zensim.viz.terrain import terrain_commands
        from zensim.robots.terrain import geometry

        terrain = terrain_from_table(COURSE)
        shapes = geometry(terrain)
        commands = [umsgpack.unpackb(c) for c in terrain_commands(terrain)]
        assert commands[0] == {"type": "delete", "path": "/terrain"}
        drawn = [c for c in commands if c["type"] == "set_object"]
        assert len(drawn) == len(shapes.blocks) + len(shapes.prisms) + len(shapes.fields) == 4 + 3 + 6 + 1 + 1 + 1
        assert all(c["path"].startswith("/terrain/") for c in drawn)
        kinds = [c["object"]["geometries"][0]["type"] for c in drawn]
        assert kinds.count("BoxGeometry") == len(shapes.blocks) and kinds.count("BufferGeometry") == 2
        # The rough patch is drawn at its grid: one vertex per grid point, at the model's heights.
        field = shapes.fields[0]
        rough = drawn[-1]["object"]["geometries"][0]["data"]["attributes"]["position"]
        vertices = np.frombuffer(rough["array"].data, np.float32).reshape(-1, 3)  # meshcat's float32 typed array
        assert rough["itemSize"] == 3 and len(vertices) == field.heights.size
        np.testing.assert_allclose(np.sort(vertices[:, 2]), np.sort(field.heights.ravel()), atol=1e-6)
        assert [umsgpack.unpackb(c) for c in terrain_commands(None)] == [{"type": "delete", "path": "/terrain"}]
