"""Every program in examples/ runs as a user runs it (`python examples/X.py --connect ...`) against a real
stack (router, sim, bridge where it needs one), and does what it says: the robot moves, the sim pauses
and steps, the recording holds the samples."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from pathlib import Path

from mcap.reader import make_reader

from support import REPO, Latest, Service, wait_for
from zensim.schemas import JointState, Keys, SimStatus

EXAMPLES = REPO / "examples"
JOINT = "left_elbow_joint"
ELBOW = 18  # its index in the G1's joint order (info/robot)


def run_example(name: str, endpoint: str, *args: str, timeout_s: float = 120) -> str:
    """Run examples/<name>.py to its end; return its output (the test fails with it on a non-zero exit)."""
    result = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), "--connect", endpoint, *args],
                            capture_output=True, text=True, timeout=timeout_s, cwd=REPO)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def wait_alive(zsession, robot: str, service: str = "sim", timeout_s: float = 60) -> None:
    wait_for(lambda: list(zsession.liveliness().get(Keys(robot).alive(service), timeout=1.0)), timeout_s,
             f"{service} of {robot} alive")


def test_every_example_is_run_by_a_test() -> None:
    programs = {path.stem for path in EXAMPLES.glob("*.py")} - {"common"}
    tested = {name for name in programs if f'"{name}"' in Path(__file__).read_text()}
    assert programs == tested, f"examples without a test: {sorted(programs - tested)}"


def test_read_states_prints_joint_states_and_the_status(start_service, zsession, router_endpoint, robot_id) -> None:
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, robot_id)
    out = run_example("read_states", router_endpoint, "--robot", robot_id, "--count", "3")
    assert f"{robot_id}: 29 joints, mode fixed" in out, out
    assert sum(line.startswith("t=") for line in out.splitlines()) == 3 and "left_hip_pitch_joint=" in out, out
    assert "status: rtf=" in out and "fallen=False" in out, out


def test_send_target_moves_the_joint_through_the_bridge(start_service, zsession, router_endpoint, robot_id) -> None:
    start_service("sim", "--mode", "fixed")
    start_service("bridge")
    wait_alive(zsession, robot_id, "bridge")
    joints = Latest(zsession, Keys(robot_id).joints, JointState)
    out = run_example("send_target", router_endpoint, "--robot", robot_id, JOINT, "0.9")
    assert f"target {JOINT} = 0.9 rad sent" in out
    joints.wait(lambda m: abs(m.q[ELBOW] - 0.9) < 0.05, 20, "the elbow at 0.9 rad")


def test_stream_motors_swings_the_joint(start_service, zsession, router_endpoint, robot_id) -> None:
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, robot_id)
    joints = Latest(zsession, Keys(robot_id).joints, JointState)
    seen: list[float] = []

    def watch() -> None:
        while not done.is_set():
            if joints.value is not None:
                seen.append(joints.value.q[ELBOW])
            done.wait(0.01)

    done = threading.Event()
    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        out = run_example("stream_motors", router_endpoint, "--robot", robot_id, JOINT, "--seconds", "3")
    finally:
        done.set()
        watcher.join()
    sent = int(out.split("sent ")[1].split()[0])
    assert sent >= 150, out  # ~100 Hz for 3 s, on a loaded machine
    assert max(seen) > 0.3 and min(seen) < -0.3, "the elbow followed the +-0.5 rad sine"


def test_reset_pause_pauses_steps_resumes_and_resets(start_service, zsession, router_endpoint, robot_id) -> None:
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, robot_id)
    status = Latest(zsession, Keys(robot_id).sim_status, SimStatus)
    episode = status.wait(what="a status").episode
    out = run_example("reset_pause", router_endpoint, "--robot", robot_id)
    lines = out.splitlines()
    paused_at = float(lines[0].split("t=")[1].split()[0])
    stepped_to = float(lines[1].split("t=")[1].split()[0])
    assert lines[1].startswith("stepped 50 steps") and math.isclose(stepped_to - paused_at, 50 * 0.002, abs_tol=1e-9), out
    assert lines[2] == "resumed" and lines[3].startswith("reset: episode"), out
    status.wait(lambda m: not m.paused and m.episode != episode, 10, "running again, in a new episode")


def test_lockstep_policy_drives_the_joint_to_its_goal(start_service, zsession, router_endpoint, robot_id) -> None:
    start_service("sim", "--mode", "fixed", "--clock", "lockstep")
    wait_alive(zsession, robot_id)
    out = run_example("lockstep_policy", router_endpoint, "--robot", robot_id, JOINT, "0.8", "--ticks", "150")
    last = out.strip().splitlines()[-1]
    assert last.startswith("t=3.000 s"), out  # 150 ticks of 20 ms, exactly: lockstep
    assert abs(float(last.split(f"{JOINT}=")[1].split()[0]) - 0.8) < 0.1, out


def test_drive_world_commands_every_robot_in_one_request(start_service, zsession, router_endpoint, robot_id,
                                                         tmp_path: Path) -> None:
    world = tmp_path / "pair.toml"
    world.write_text(f'id = "{robot_id}-w"\n[[robots]]\nid = "{robot_id}-a"\n'
                     f'[[robots]]\nid = "{robot_id}-b"\nxy = [1.5, 0.0]\n')
    start_service("sim", "--world", str(world), "--mode", "fixed", "--clock", "lockstep")
    wait_alive(zsession, f"{robot_id}-w", "world", 120)
    out = run_example("drive_world", router_endpoint, "--world", f"{robot_id}-w", "--ticks", "250")
    assert f"robots {robot_id}-a, {robot_id}-b" in out, out
    last = out.strip().splitlines()[-1]
    assert last.startswith("t=5.000 s"), out  # 250 advances of 20 ms: the fixed G1's gains settle in ~4 s
    for robot in ("a", "b"):
        assert abs(float(last.split(f"{robot_id}-{robot} ")[1].split(",")[0]) - 0.3) < 0.05, out


def test_record_writes_every_key_into_mcap(start_service, zsession, router_endpoint, robot_id, tmp_path: Path) -> None:
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, robot_id)
    path = tmp_path / "run.mcap"
    out = run_example("record", router_endpoint, "--robot", robot_id, "-o", str(path), "--seconds", "2")
    assert f"to {path}" in out
    with path.open("rb") as stream:
        topics = [channel.topic for _, channel, _ in make_reader(stream).iter_messages()]
    assert topics.count(Keys(robot_id).joints) > 100, out  # 100 Hz for 2 s
    assert Keys(robot_id).sim_status in topics and Keys(robot_id).odom in topics
