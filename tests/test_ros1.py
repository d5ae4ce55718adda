"""The ROS 1 gateway's rules (services/ros1/mapping.py), without ROS or Zenoh: names, input checks,
the GUI's moved sliders, the odometry's frames, mesh URLs."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import pytest

from zensim.ros1.mapping import (
    CommandGate,
    GuiChanges,
    InputError,
    P3dOdometry,
    RateGate,
    RobotJoints,
    RosNames,
    mesh_references,
    with_mesh_urls,
)
from support import REPO
from zensim.schemas import JointTargets, Odometry

ARM = RobotJoints(names=("shoulder", "elbow"), q_min=(-2.0, 0.0), q_max=(2.0, 2.5), run_id="r1", mesh_paths=())


def classic(robot_id: str = "g1", **overrides: str) -> RosNames:
    settings = dict(namespace="", joint_states="joint_states", command="{joint}_controller/command",
                    gui="/gui_commands", odom="/ground_truth_odom", imu="imu", clock="/clock", tf="/tf")
    settings.update(overrides)
    return RosNames.of(robot_id, **settings)


def test_default_names_are_the_classic_workspace_s() -> None:
    names = classic()
    assert names.joint_states == "/g1_description/joint_states"
    assert names.command("left_elbow_joint") == "/g1_description/left_elbow_joint_controller/command"
    assert (names.gui, names.odom, names.clock, names.tf) == ("/gui_commands", "/ground_truth_odom", "/clock", "/tf")
    assert names.imu == "/g1_description/imu"


def test_names_follow_the_robot_id_and_the_namespace_setting() -> None:
    assert classic("h1").joint_states == "/h1_description/joint_states"
    assert classic("h1", namespace="robots/h1").command("knee") == "/robots/h1/knee_controller/command"
    with pytest.raises(ValueError, match="joint"):
        classic(command="controller/command")


def test_a_position_inside_the_limits_passes_and_anything_else_is_refused() -> None:
    assert ARM.check_position("elbow", 2.5) == 2.5  # the limit itself: a slider at its end
    for joint, value, reason in [("elbow", 2.6, "outside"), ("elbow", -0.1, "outside"), ("elbow", math.nan, "finite"),
                                 ("elbow", math.inf, "finite"), ("wrist", 0.0, "unknown"), ("elbow", 1e300, "outside")]:
        with pytest.raises(InputError, match=reason):
            ARM.check_position(joint, value)


def test_a_joint_state_becomes_targets_or_is_refused_whole() -> None:
    assert ARM.joint_targets(["elbow", "shoulder"], [1.0, -1.0]) == JointTargets(names=("elbow", "shoulder"), q=(1.0, -1.0))
    bad = [([], [], "no names"), (["elbow"], [1.0, 2.0], "positions"), (["elbow", "elbow"], [1.0, 1.0], "more than once"),
           (["elbow", "tail"], [1.0, 0.0], "unknown"), (["elbow", "shoulder"], [1.0, math.nan], "finite"),
           (["elbow", "shoulder"], [1.0, 3.0], "outside")]
    for names, positions, reason in bad:
        with pytest.raises(InputError, match=reason):
            ARM.joint_targets(names, positions)


def test_the_gui_passes_on_only_the_sliders_that_moved() -> None:
    """joint_state_publisher_gui repeats every slider at 10 Hz: only a moved one may reach the bridge,
    or a reset of the sim would be undone a tenth of a second later."""
    gui = GuiChanges()
    first = JointTargets(names=("shoulder", "elbow"), q=(0.0, 0.0))
    assert gui.changed(first) == first  # the first message: every slider counts
    assert gui.changed(first) is None  # the same again: nothing moved
    assert gui.changed(JointTargets(names=("shoulder", "elbow"), q=(0.0, 1.2))) == JointTargets(names=("elbow",), q=(1.2,))
    gui.forget()
    assert gui.changed(first) == first


def test_the_rate_gate_thins_a_faster_sim_and_starts_over_after_a_reset() -> None:
    gate = RateGate(100.0)
    times = [i * 0.002 for i in range(501)]  # 1 s of a 500 Hz sim
    assert sum(gate.due(t) for t in times) == 101
    gate = RateGate(100.0)
    assert all(gate.due(i * 0.01) for i in range(100))  # a 100 Hz sim: every state
    assert gate.due(0.0)  # time went back (a reset): publish at once


def test_the_command_gate_forwards_one_per_period_per_key_and_the_newest_of_a_burst_later() -> None:
    gate: CommandGate[str, float] = CommandGate(100.0)
    assert gate.offer("elbow", 0.1, 0.0) == (True, False)
    assert gate.offer("knee", 0.2, 0.001) == (True, False), "another topic has its own budget"
    assert gate.offer("elbow", 0.3, 0.002) == (False, False)
    assert gate.offer("elbow", 0.4, 0.003) == (False, True), "a held one replaced is shed"
    assert gate.due(0.005) == []
    assert gate.due(0.0101) == [("elbow", 0.4)], "the newest of the burst goes in its turn"
    assert gate.due(0.03) == []
    assert gate.offer("elbow", 0.5, 0.015) == (False, False)
    assert gate.offer("elbow", 0.6, 0.0202) == (True, True), "due and newer: sent at once, the held one shed"
    unlimited: CommandGate[str, float] = CommandGate(0)
    assert all(unlimited.offer("elbow", 0.1, 0.0) == (True, False) for _ in range(5))


def test_odometry_is_p3d_s_pose_and_world_frame_twist() -> None:
    half = math.sqrt(0.5)
    odom = Odometry(sim_time_s=1.0, seq=1, pos=(1.0, 2.0, 0.8), quat_wxyz=(half, 0.0, 0.0, half),  # yaw +90 deg
                    lin_vel_world=(0.5, 0.0, 0.0), ang_vel_body=(1.0, 0.0, 0.3))
    p3d = P3dOdometry.of(odom)
    assert p3d.position == (1.0, 2.0, 0.8)
    assert p3d.orientation_xyzw == (0.0, 0.0, half, half)
    assert p3d.linear == (0.5, 0.0, 0.0)
    assert p3d.angular == pytest.approx((0.0, 1.0, 0.3))  # body x is world y after a 90 deg yaw


def test_mesh_references_point_at_the_gateway_and_nothing_else_changes() -> None:
    urdf = ('<robot name="r"><link name="a"><visual><geometry><mesh filename="meshes/a b.STL"/></geometry></visual>'
            "<collision><geometry><mesh scale='1 1 1' filename='package://g1/meshes/c.STL'/></geometry></collision>"
            '</link><link name="d"><visual><geometry><box size="1 1 1"/></geometry></visual></link></robot>')
    rewritten = with_mesh_urls(urdf, "http://127.0.0.1:7011/")
    assert mesh_references(rewritten) == ["http://127.0.0.1:7011/meshes/a%20b.STL", "http://127.0.0.1:7011/g1/meshes/c.STL"]
    assert rewritten.replace("http://127.0.0.1:7011/meshes/a%20b.STL", "meshes/a b.STL").replace(
        "http://127.0.0.1:7011/g1/meshes/c.STL", "package://g1/meshes/c.STL") == urdf


def test_without_rospy_the_gateway_says_so_in_one_line() -> None:
    """The project's venv does not see Debian's rospy by itself; pointed nowhere, the gateway cannot start."""
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "zensim", "ros1", "--ros-python-path", "/nonexistent"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.startswith("zensim ros1:")]
    assert len(lines) == 1 and "cannot import rospy" in lines[0] and "docs/ros.md" in lines[0], result.stderr
    assert "Traceback" not in result.stderr


LAUNCH_FILES = sorted((REPO / "deploy").rglob("*.launch"))


@pytest.mark.skipif(not Path("/usr/bin/roslaunch").exists(), reason="needs Debian's ROS 1 (roslaunch)")
@pytest.mark.parametrize("launch", LAUNCH_FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_launch_file_passes_roslaunch_s_own_check(launch: Path) -> None:
    """roslaunch's own check (rlutil.check_roslaunch, what `roslaunch-check` runs): the XML parses, every
    node's package and program exist. A comment with two dashes in a row once made display.launch unreadable."""
    check = "import sys, roslaunch.rlutil; print(roslaunch.rlutil.check_roslaunch(sys.argv[1]) or 'ok')"
    result = subprocess.run(["/usr/bin/python3", "-c", check, str(launch)], capture_output=True, text=True,
                            timeout=60, cwd=launch.parent)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stdout + result.stderr


def test_there_is_a_launch_file_to_check() -> None:
    assert REPO / "deploy" / "ros1" / "display.launch" in LAUNCH_FILES
