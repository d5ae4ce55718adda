"""Terrain as users run it: `zensim sim --terrain FILE`, a world file's `[terrain]`, the description on
info/robot and world/info, a recording and its replay carrying it, and the viewer drawing it (headless
chromium). Real processes, real Zenoh on loopback, real MuJoCo."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from browser import Browser, chromium_binary, decode_png
from support import REPO, Latest, free_port, wait_for
from test_lockstep_process import advance, scripted_command
from test_record_process import start_recorder, stop_recorder, zensim
from test_sim_process import robot_info, wait_alive
from zensim.mcapfile import read_recording
from zensim.robots.terrain import load_terrain
from zensim.schemas import JointState, Keys, Odometry, SimStatus

PLATFORM_M = 0.3
TERRAIN = f"""
# A platform under the robot, and a slope, stairs, rough ground and stones around it.
[[features]]
type = "box"
size_m = [1.0, 1.0, {PLATFORM_M}]
pos = [0.0, 0.0, {PLATFORM_M / 2}]

[[features]]
type = "slope"
angle_deg = 12
length_m = 2.0
width_m = 1.5
top_m = 0.5
at = [0.8, -1.6]

[[features]]
type = "stairs"
step_height_m = 0.12
step_depth_m = 0.3
count = 4
width_m = 1.2
at = [-0.6, 1.0]
direction_deg = 90

[[features]]
type = "rough"
size_m = [1.6, 1.6]
amplitude_m = 0.08
cell_m = 0.1
seed = 5
at = [1.6, 1.2]

[[features]]
type = "stones"
rows = 3
columns = 2
height_m = 0.2
at = [-2.0, -1.0]
"""
FLAT_SPAWN_M = 0.85
"""The G1's floating spawn height on the flat floor (its control.toml)."""
FLAT_STANDING_M = (0.70, 0.76)
"""Where its pelvis settles on the flat floor, holding the squat."""


@pytest.fixture
def terrain_file(tmp_path: Path) -> Path:
    path = tmp_path / "terrain.toml"
    path.write_text(TERRAIN)
    return path


def as_json(value: object) -> object:
    return json.loads(json.dumps(value))


class TestSim:
    def test_info_robot_describes_the_terrain_and_the_robot_stands_on_it(self, start_service, zsession, robot_id,
                                                                           terrain_file) -> None:
        keys = Keys(robot_id)
        odom = Latest(zsession, keys.odom, Odometry)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim", "--terrain", str(terrain_file))
        wait_alive(zsession, keys)
        info = robot_info(zsession, keys)
        import msgspec

        expected = json.loads(msgspec.json.encode(load_terrain(terrain_file)))
        assert info["terrain"] == expected
        assert [f["type"] for f in info["terrain"]["features"]] == ["box", "slope", "stairs", "rough", "stones"]
        # Spawned over the platform, it settles on it and stands (the watchdog holds the default pose).
        assert info["base_height_m"]["floating"] == pytest.approx(FLAT_SPAWN_M + PLATFORM_M, abs=1e-6)
        settled = odom.wait(lambda m: m.sim_time_s > 1.5, timeout_s=30, what="1.5 s of sim time")
        low, high = FLAT_STANDING_M
        assert low + PLATFORM_M < settled.pos[2] < high + PLATFORM_M, settled.pos
        assert not status.wait(lambda m: m.sim_time_s > 1.5, timeout_s=10, what="a status").fallen

    def test_without_terrain_info_robot_says_flat(self, start_service, zsession, robot_id) -> None:
        keys = Keys(robot_id)
        start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        assert robot_info(zsession, keys)["terrain"] is None

    @pytest.mark.parametrize("text, said", [
        ('[[features]]\ntype = "rough"\nsize_m = [100, 100]\namplitude_m = 0.1\ncell_m = 0.001\n', "cell_m"),
        ('[[features]]\ntype = "rough"\nsize_m = [60, 60]\namplitude_m = 0.1\ncell_m = 0.02\n', "3000 x 3000 cells"),
        ('[[features]]\ntype = "slope"\nangle_deg = nan\nlength_m = 3\n', "angle_deg"),
        ('[[features]]\ntype = "stairs"\nstep_height_m = 0.1\nstep_depth_m = 0.3\ncount = 100000\n', "count"),
        ('[[features]]\ntype = "box"\nsize_m = [1, -1, 1]\npos = [0, 0, 0]\n', "size_m"),
        ('[[features]]\ntype = "slope"\nangle_deg = 10\nlength_m = 3\nwidht_m = 2\n', "widht_m"),
    ])
    def test_a_bad_terrain_file_stops_the_sim_with_one_line(self, start_service, tmp_path, text, said) -> None:
        path = tmp_path / "bad.toml"
        path.write_text(text)
        sim = start_service("sim", "--terrain", str(path))
        assert sim.proc.wait(30) == 2, sim.log()
        lines = [line for line in sim.log().splitlines() if "terrain (--terrain / ZENSIM_SIM_TERRAIN)" in line]
        assert len(lines) == 1 and said in lines[0], sim.log()
        assert "Traceback" not in sim.log()


class TestWorld:
    def test_a_world_file_terrain_table_builds_under_every_robot(self, start_service, zsession, robot_id,
                                                                 tmp_path) -> None:
        world_id, a, b = f"{robot_id}-w", f"{robot_id}-a", f"{robot_id}-b"
        path = tmp_path / "world.toml"
        path.write_text(f'id = "{world_id}"\n[[robots]]\nid = "{a}"\n[[robots]]\nid = "{b}"\nxy = [3.0, 0.0]\n'
                        f'[terrain]\n[[terrain.features]]\ntype = "box"\nsize_m = [1, 1, 0.2]\npos = [3, 0, 0.1]\n')
        start_service("sim", "--world", str(path))
        wait_alive(zsession, Keys(b))
        replies = list(zsession.get(Keys(world_id).world_info + "?format=json", timeout=5.0))
        world = json.loads(replies[0].ok.payload.to_bytes())
        box = {"type": "box", "size_m": [1.0, 1.0, 0.2], "pos": [3.0, 0.0, 0.1], "rpy_deg": [0.0, 0.0, 0.0]}
        assert world["terrain"] == {"type": "terrain", "features": [box]}
        info_a, info_b = robot_info(zsession, Keys(a)), robot_info(zsession, Keys(b))
        assert info_a["terrain"] == info_b["terrain"] == world["terrain"]
        assert info_b["base_height_m"]["floating"] == pytest.approx(info_a["base_height_m"]["floating"] + 0.2, abs=1e-6)

    def test_a_typo_in_a_world_terrain_or_two_terrains_are_refused(self, start_service, robot_id, tmp_path,
                                                                   terrain_file) -> None:
        path = tmp_path / "world.toml"
        head = f'id = "{robot_id}-w"\n[[robots]]\nid = "{robot_id}-a"\n'
        path.write_text(head + '[terrain]\n[[terrain.features]]\ntype = "box"\nsize_m = [1, 1, 1]\npos = [3, 0, 0]\n'
                               'rpy = [0, 0, 1]\n')
        sim = start_service("sim", "--world", str(path))
        assert sim.proc.wait(30) == 2, sim.log()
        assert "'rpy'" in sim.log(), sim.log()
        path.write_text(head + '[terrain]\n')
        sim = start_service("sim", "--world", str(path), "--terrain", str(terrain_file))
        assert sim.proc.wait(30) == 2, sim.log()
        assert "give one" in sim.log(), sim.log()


def test_a_recording_carries_the_terrain_and_its_replay_serves_it(start_service, zsession, robot_id, tmp_path,
                                                                   terrain_file) -> None:
    keys = Keys(robot_id)
    start_service("sim", "--terrain", str(terrain_file), "--mode", "fixed")
    wait_alive(zsession, keys)
    path = tmp_path / "run.mcap"
    recorder = start_recorder(start_service, path, zsession, keys)
    time.sleep(0.5)  # some states after the description
    stop_recorder(recorder)
    terrain = load_terrain(terrain_file)
    recording = read_recording(path)
    assert recording.robot_info is not None and recording.robot_info.terrain == terrain
    replay_id = robot_id + "r"
    start_service("replay", str(path), "--robot-id", replay_id, "--rate", "0.2")
    wait_alive(zsession, Keys(replay_id))
    import msgspec

    assert robot_info(zsession, Keys(replay_id))["terrain"] == json.loads(msgspec.json.encode(terrain))


def test_a_lockstep_run_on_terrain_resims_to_zero(start_service, zsession, robot_id, tmp_path, terrain_file) -> None:
    """resim rebuilds the recorded terrain (RobotInfo.terrain): without it the feet would meet the floor
    0.3 m lower than the platform they stood on, and the run would not repeat."""
    keys = Keys(robot_id)
    joints = Latest(zsession, keys.joints, JointState)
    start_service("sim", "--clock", "lockstep", "--terrain", str(terrain_file))
    wait_alive(zsession, keys)
    path = tmp_path / "run.mcap"
    recorder = start_recorder(start_service, path, zsession, keys)
    info = robot_info(zsession, keys)
    q = list(joints.wait(what="the initial state").q)
    for k in range(80):  # 1.6 s: the robot lands on the platform and swings on it
        q = advance(zsession, keys, scripted_command(k, info, q))["joints"]["q"]
    time.sleep(0.3)  # the last states reach the recorder
    stop_recorder(recorder)
    result = zensim("resim", str(path))
    assert result.returncode == 0, result.stderr
    assert "joint position 0 rad, base position 0 m, base orientation 0 rad" in result.stdout, result.stdout


@pytest.fixture
def browser() -> Iterator[Browser]:
    if chromium_binary() is None:
        pytest.fail("chromium is needed: apt-get install -y --no-install-recommends chromium")
    with Browser(width=1000, height=700) as b:
        yield b


def terrain_pixels(rgb: np.ndarray) -> np.ndarray:
    """Mask of the terrain's sandy colour as lit: warm pixels, red well above blue (the background is blue,
    the floor grid and the robot grey)."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (r > g) & (g > b) & (r - b > 40)


def test_the_viewer_draws_the_terrain(start_service, zsession, robot_id, terrain_file, browser) -> None:
    keys = Keys(robot_id)
    port = free_port()
    start_service("sim", "--mode", "fixed", "--terrain", str(terrain_file))
    viz = start_service("viz", "--port", str(port), "--ghost", "false")
    wait_alive(zsession, keys, "viz")
    browser.goto(f"http://127.0.0.1:{port}/")
    browser.wait("window.zensim && zensim.sceneReady", 60, "the robot and the terrain drawn")
    frames = browser.eval("zensim.framesApplied")
    browser.wait(f"zensim.framesApplied > {frames + 2}", 30, "more frames drawn")
    png = browser.screenshot()
    with_terrain = terrain_pixels(decode_png(png))
    if os.environ.get("ZENSIM_SAVE_SCREENSHOT"):  # docs/terrain.png, as docs/screenshot.png is made
        (REPO / "docs" / "terrain.png").write_bytes(png)
    browser.eval("(() => { viewer.set_property(['terrain'], 'visible', false); viewer.set_dirty(); return true; })()")
    browser.eval("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))")
    without = terrain_pixels(decode_png(browser.screenshot()))
    assert with_terrain.mean() > 0.01, f"only {with_terrain.mean():.4f} of the page shows the terrain's colour"
    assert without.mean() < 0.1 * with_terrain.mean(), "the sandy pixels are not the terrain's"
    assert "Traceback" not in viz.log()
