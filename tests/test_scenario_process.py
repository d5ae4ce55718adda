"""`zensim scenario FILE` and `zensim course` as users run them: real sims, `zensim loco`, a plain client.

Lockstep throughout: the walking controller (or the user's) is the clock, so sim time moves at the pace
of its commands whatever loads the machine, and the scenario's events land on sim time.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from xml.etree import ElementTree
from pathlib import Path

import pytest

from support import wait_for
from zensim.mcapfile import read_recording
from zensim.schemas import Keys

SCENARIO = """
name = "walk-and-shove"
end_s = 9.0

[[events]]
at_s = 0.0
type = "loco"
verb = "walk"

[[events]]
at_s = 3.0
type = "velocity"
vx = 0.4

[[events]]
at_s = 5.5
type = "push"
direction = [0, 1, 0]
magnitude_n = 60
duration_s = 0.2
"""


def finished(service, timeout_s: float) -> int:
    service.proc.wait(timeout_s)
    return service.proc.returncode


def start_walker(start_service, zsession, robot_id: str, *sim_args: str):
    sim = start_service("sim", "--clock", "lockstep", *sim_args)
    keys = Keys(robot_id)
    loco = start_service("loco")
    wait_for(lambda: any(r.ok is not None for r in zsession.liveliness().get(keys.alive("loco"), timeout=1)),
             60, "alive/loco")
    return sim, loco


def test_a_scenario_pushes_and_walks_the_reference_controller_and_reports_it(start_service, zsession, robot_id, tmp_path):
    start_walker(start_service, zsession, robot_id)
    path = tmp_path / "shove.toml"
    path.write_text(SCENARIO)
    result_path = tmp_path / "result.json"
    scenario = start_service("scenario", str(path), "--result", str(result_path))
    assert finished(scenario, 240) == 0, scenario.log()
    out = scenario.log()
    assert "survived: yes" in out and "distance:" in out and "push at 5.5" in out, out
    result = json.loads(result_path.read_text())
    assert result["completed"] and result["survived"], result
    # 0.4 m/s from t = 3 s to 9 s: about 2 m forward (the stand-up adds almost nothing), and a 60 N shove
    # to the left that the policy rides out.
    assert 1.2 < result["distance_m"] < 3.5, result
    assert result["tracking_error_m_s"] is not None and result["tracking_error_m_s"] < 0.3, result
    push = result["pushes"][0]
    assert push["force_n"] == [0.0, 60.0, 0.0] and abs(push["at_s"] - 5.5) < 0.2, push
    assert push["recovered_s"] is not None and push["recovered_s"] < 3.0, push
    assert 10 < result["peak_torque_nm"] < 300 and result["peak_torque_joint"].endswith("_joint"), result
    assert [e["type"] for e in result["events"]] == ["loco", "velocity", "push"] and result["refused_events"] == 0


REPLAYED = """
end_s = 4.0

[[events]]
at_s = 0.0
type = "loco"
verb = "walk"

[[events]]
at_s = 1.0
type = "velocity"
vx = 0.4

[[events]]
at_s = 2.013
type = "push"
direction = [0, 1, 0]
magnitude_n = 60
duration_s = 0.1

[[events]]
at_s = 2.5
type = "faults"
request = { verb = "set", seed = 3, joints = [{ joint = "left_knee_joint", torque_scale = 0.7 }], sensors = { gyro_noise_std_rad_s = 0.05 } }
"""
"""Walking, a push mid-step and faults with seeded noise: everything that could land a step early or late."""
DETERMINED = ("state/joints", "state/odom", "state/imu", "state/contacts", "cmd/motors")
"""What the sim and the controller publish per step of sim time; state/sim and state/loco go at wall-clock
rates (their figures are the wall clock's: rtf, jitter, run ids), so they are left out."""


def recorded_run(start_service, zsession, robot_id: str, tmp_path: Path) -> dict[str, list]:
    """One run of REPLAYED against the reference controller, recorded; its messages up to end_s by key."""
    env = {"ZENSIM_ROBOT_ID": robot_id}
    sim = start_service("sim", "--clock", "lockstep", env=env)
    loco = start_service("loco", env=env)
    wait_for(lambda: any(r.ok is not None for r in zsession.liveliness().get(Keys(robot_id).alive("loco"), timeout=1)),
             60, "alive/loco")
    path = tmp_path / f"{robot_id}.toml"
    path.write_text(REPLAYED)
    scenario = start_service("scenario", str(path), "--record", str(tmp_path / f"{robot_id}.mcap"), env=env)
    assert finished(scenario, 240) == 0, scenario.log()
    loco.stop()
    sim.stop()
    recording = read_recording(tmp_path / f"{robot_id}.mcap")
    return {key: [m for m in recording.of(key) if 0.0 < m.sim_time_s <= 4.0] for key in DETERMINED[:4]} | {
        "cmd/motors": recording.of("cmd/motors")[:150]}  # 150 ticks of 20 ms: 3 s of commands


def test_the_same_scenario_and_controller_give_bit_identical_recordings(start_service, zsession, robot_id, tmp_path):
    """Each push, fault and velocity is sent ahead with its sim time: it acts at the same step in both runs
    whatever the load, and the seeded noise draws the same numbers, so every state and command is the same."""
    first = recorded_run(start_service, zsession, robot_id, tmp_path)
    second = recorded_run(start_service, zsession, robot_id + "b", tmp_path)
    assert len(first["state/joints"]) == 200 and len(first["cmd/motors"]) == 150, {k: len(v) for k, v in first.items()}
    pushed = [m for m in first["state/odom"] if 2.02 <= m.sim_time_s <= 2.12]
    assert max(abs(m.lin_vel_world[1]) for m in pushed) > 0.1, "the push moved the robot"
    for key in DETERMINED:
        assert len(first[key]) == len(second[key]), key
        for a, b in zip(first[key], second[key]):
            assert a == b, f"{key} differs at {getattr(a, 'sim_time_s', '')}: {a} != {b}"


@pytest.mark.parametrize("body, line", [
    ('end_s = 5\n[[events]]\nat_s = 1\ntype = "jump"\n', "an event's type is one of push, band, velocity, loco, faults"),
    ('end_s = 5\n[[events]]\nat_s = 1\ntype = "push"\ndirection = [1, 0, 0]\nmagnitude_n = nan\nduration_s = 0.2\n',
     "$.events[0].magnitude_n"),
    ('end_s = 5\n[[events]]\nat_s = 1\ntype = "push"\ndirection = [1, 0, 0]\nmagnitude_n = 1e9\nduration_s = 0.2\n',
     "$.events[0].magnitude_n"),
    (None, "more than 4194304"),
])
def test_a_bad_scenario_is_refused_with_one_line_before_anything_is_sent(body, line, tmp_path):
    path = tmp_path / "bad.toml"
    if body is None:  # 10^6 events: refused by its size before a byte is parsed
        with path.open("w") as file:
            file.write("end_s = 5\n")
            file.writelines('[[events]]\nat_s = 1\ntype = "velocity"\n' for _ in range(1_000_000))
    else:
        path.write_text(body)
    # No router, no sim: a refused scenario never opens a session.
    done = subprocess.run([sys.executable, "-m", "zensim", "scenario", str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("zensim scenario: ") and line in lines[0], done.stderr


def test_a_faults_event_is_refused_whole_when_the_sim_does_not_serve_ctl_faults(start_service, zsession, robot_id, tmp_path):
    start_service("sim", "--clock", "lockstep")
    keys = Keys(robot_id)
    wait_for(lambda: any(r.ok is not None for r in zsession.liveliness().get(keys.alive("sim"), timeout=1)), 60, "alive/sim")
    path = tmp_path / "weak.toml"
    path.write_text('end_s = 5\n[[events]]\nat_s = 1\ntype = "faults"\nrequest = { joint = "left_knee_joint", torque_scale = 0.6 }\n')
    scenario = start_service("scenario", str(path))
    if hasattr(keys, "ctl_faults"):  # the sim serves ctl/faults: the event is forwarded and its answer reported
        start_service("loco", "--start", "walk")  # a clock for the lockstep sim
        assert finished(scenario, 120) == 0, scenario.log()
        assert "event faults" not in scenario.log() or "refused:" in scenario.log()
        return
    assert finished(scenario, 60) == 2, scenario.log()
    # Until the sim serves ctl/faults, one line says why the file cannot play; nothing was sent.
    lines = [line for line in scenario.log().splitlines() if line.startswith("zensim scenario:")]
    assert len(lines) == 1 and "does not serve ctl/faults" in lines[0], scenario.log()


def test_a_short_course_runs_the_reference_controller_end_to_end_and_writes_the_table(tmp_path):
    """`zensim course` starts its own router, a lockstep sim and `zensim loco` per run, and stops them all."""
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "zensim", "course", "--items", "flat,push_right", "--seeds", "1",
                           "--output-dir", str(out), "--record", "true", "--log-level", "WARNING"],
                          capture_output=True, text=True, timeout=400)
    assert done.returncode == 0, done.stdout + done.stderr
    table = (out / "course.md").read_text()
    assert "| flat | 1/1 |" in table and "| push_right | 1/1 |" in table, table
    runs = json.loads((out / "course.json").read_text())["runs"]
    assert [(r["item"], r["seed"]) for r in runs] == [("flat", 0), ("push_right", 0)]
    flat, pushed = (r["result"] for r in runs)
    assert flat["completed"] and flat["survived"] and 3.0 < flat["distance_m"] < 5.0, flat
    assert [round(math.hypot(*p["force_n"])) for p in pushed["pushes"]] == [40, 80, 120], pushed
    assert all(p["force_n"][1] > 0 for p in pushed["pushes"]), pushed  # from the right: towards +y
    assert (out / "flat-s0.mcap").stat().st_size > 100_000 and (out / "push_right-s0.mcap").stat().st_size > 100_000
    assert "flat" in done.stdout and "survived" in done.stdout, done.stdout
    figure = ElementTree.parse(out / "course.svg").getroot()  # the plot image: an SVG, one dot per run
    dots = [c for c in figure.iter("{http://www.w3.org/2000/svg}circle")]
    assert [d.find("{http://www.w3.org/2000/svg}title").text.split(":")[0] for d in dots] == ["seed 0", "seed 0"]
    assert {t.text for t in figure.iter("{http://www.w3.org/2000/svg}text")} >= {"flat", "push_right", "1/1"}


def test_course_variants_run_each_seed_on_its_own_robot_and_say_which(tmp_path):
    """`--variants true`: before each run the course resets the robot into the variant its seed draws."""
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "zensim", "course", "--items", "flat", "--seeds", "2", "--variants",
                           "true", "--output-dir", str(out), "--log-level", "WARNING"],
                          capture_output=True, text=True, timeout=400)
    assert done.returncode == 0, done.stdout + done.stderr
    runs = json.loads((out / "course.json").read_text())["runs"]
    variants = [run["variant"] for run in runs]
    assert [v["seed"] for v in variants] == [0, 1] and variants[0]["mass_kg"] != variants[1]["mass_kg"], variants
    for variant in variants:
        assert variant["mass_kg"] != variant["nominal_mass_kg"] and 0.6 <= variant["friction_scale"] <= 1.4, variant
        assert all(0.85 <= s <= 1.0 for s in variant["motor_strength"]), variant
    assert all(run["result"]["completed"] for run in runs), runs
    assert f"variant 1: {variants[1]['mass_kg']:.1f} kg" in (out / "course.md").read_text()


SQUAT_HOLDER = textwrap.dedent("""
    # A user's controller written against cmd/motors alone: hold the spawn squat with the floating gains.
    import json, sys, time, zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    robot = sys.argv[2]
    with zenoh.open(conf) as session:
        motors = session.declare_publisher(f"zensim/{robot}/cmd/motors")
        command = None
        while True:
            if command is None:  # (again) ask the sim for the pose and gains; the course starts a sim per run
                for reply in session.get(f"zensim/{robot}/info/robot?format=json", timeout=1.0):
                    if reply.ok is not None:
                        info = json.loads(reply.ok.payload.to_bytes())
                        command = json.dumps({"names": info["joint_names"], "q": info["default_q"]["floating"],
                                              "kp": info["gains"]["floating"]["kp"], "kd": info["gains"]["floating"]["kd"]})
                if command is None:
                    time.sleep(0.1)
                    continue
            motors.put(command)  # lockstep: each command advances the sim 20 ms
            time.sleep(0.005)
""")


def test_a_user_controller_on_cmd_motors_runs_a_course_item_and_gets_its_row(router_endpoint, robot_id, tmp_path):
    controller = subprocess.Popen([sys.executable, "-c", SQUAT_HOLDER, router_endpoint, robot_id], start_new_session=True)
    try:
        out = tmp_path / "out"
        done = subprocess.run([sys.executable, "-m", "zensim", "course", "--controller", "external", "--items", "push_front",
                               "--seeds", "1", "--output-dir", str(out), "--robot-id", robot_id, "--zenoh-mode", "client",
                               "--zenoh-connect", router_endpoint, "--log-level", "WARNING"],
                              capture_output=True, text=True, timeout=400)
    finally:
        controller.terminate()
        controller.wait(10)
    assert done.returncode == 0, done.stdout + done.stderr
    runs = json.loads((out / "course.json").read_text())["runs"]
    assert len(runs) == 1 and runs[0]["item"] == "push_front", runs
    result = runs[0]["result"]
    # The squat holder neither walks nor balances: it covers the item's 15 s (its commands are the clock) and
    # the row says what happened to it, fallen or not, with the pushes it met.
    assert result["completed"], result
    assert len(result["pushes"]) >= 1 and result["events"][0]["type"] == "velocity", result
    row = next(line for line in (out / "course.md").read_text().splitlines() if line.startswith("| push_front | 0 |"))
    assert ("| yes |" in row) == result["survived"] and result["distance_m"] < 2.0, row
