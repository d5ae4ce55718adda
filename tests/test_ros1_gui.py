"""The classic ROS 1 GUI tools against zensim, each a real program under Xvfb driven by real X input:
Debian's joint_state_publisher_gui (remapped to /gui_commands, a slider moved with xdotool) and
Debian's rviz (deploy/ros1/zensim.rviz: RobotModel + TF in frame `world`, checked in a screenshot).

The heavy tests of the ROS 1 gateway (a GUI, an X server, software OpenGL): named test_gui_*.
The test process stays out of the ROS graph; it watches the sim over Zenoh.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from ros_graph import JSP_GUI, RSP, RVIZ_CONFIG, Roscore, Stack, Tool, Xvfb
from support import Latest, ctl, wait_for
from zensim.schemas import JointState, JointTargets, Keys, Ros1Status

KEYS = Keys("g1")
BACKGROUND = (170, 200, 240)
"""zensim.rviz's background colour; the G1's materials are greys (0.2 and 0.7)."""
SLIDER = "left_hip_pitch_joint"
"""The first slider of joint_state_publisher_gui (the URDF's first joint)."""


def first_slider_groove(image: np.ndarray, width: int) -> tuple[int, int] | None:
    """A point on the first slider's groove, right of its handle, in a screenshot of the GUI's window at (0, 0).

    The sliders' grooves are blue left of the handle (Qt's Fusion style); the topmost row with a run of
    that blue is the first slider, and its groove ends where the background colour comes back to the
    right of the blue (past the handle).
    """
    window = image[:, :width].astype(int)
    blue = (window[..., 2] > 150) & (window[..., 2] - window[..., 0] > 80)
    rows = np.nonzero(blue.sum(axis=1) > 20)[0]
    if rows.size == 0:
        return None
    y = int(rows[0]) + 1
    background = window[y, 0]
    last_blue = int(np.nonzero(blue[y])[0].max())
    after = np.nonzero(np.all(window[y, last_blue:] == background, axis=-1))[0]
    if after.size == 0:
        return None
    return last_blue + int(after[0]) - 8, y


@pytest.fixture
def graph(tmp_path):
    """A roscore, the fixed-base G1 (gravity off: any pose holds) with bridge and gateway, an X server."""
    core = Roscore(tmp_path / "ros")
    stack = Stack(core, tmp_path, sim_args=("--mode", "fixed"))
    xvfb = Xvfb(tmp_path)
    tools: list[Tool] = []

    def tool(*args: str) -> Tool:
        tools.append(Tool(list(args), {**core.env, **xvfb.env}, tmp_path / f"{len(tools)}-{args[0].split('/')[-1]}.log"))
        return tools[-1]

    try:
        yield stack, xvfb, tool
    finally:
        for t in tools:
            t.stop()
        xvfb.stop()
        stack.close()
        core.stop()


def joint_q(state: JointState, names: list[str], joint: str) -> float:
    return state.q[names.index(joint)]


def test_gui_joint_state_publisher_gui_slider_moves_the_sim(graph, tmp_path) -> None:
    stack, xvfb, tool = graph
    info = ctl(stack.session, KEYS.robot_info)
    names, q_max = info["joint_names"], info["q_max"]
    assert names[0] == SLIDER
    joints = Latest(stack.session, KEYS.joints, JointState)
    status = Latest(stack.session, KEYS.ros1_status, Ros1Status)
    sent = Latest(stack.session, KEYS.joint_targets, JointTargets)
    sent.keep_history = True
    gui = tool(str(JSP_GUI), "joint_states:=/gui_commands")
    # Its title is "Node: /joint_state_publisher_gui — Joint State Publisher"; xdotool's regex stops at the dash.
    window = wait_for(lambda: xvfb.window("^Node: "), 60, "the GUI's window", 0.5)
    # The GUI's first message sets every joint (its sliders' start values); the rest repeat it.
    status.wait(lambda s: s.commands_forwarded >= 1 and s.commands_received >= 5, 30, "the GUI's messages")
    first = len(sent.history)
    assert first == 1 and len(sent.history[0].names) == len(names)
    start = dict(zip(sent.history[0].names, sent.history[0].q))
    joints.wait(lambda s: all(abs(s.q[i] - start[n]) < 0.05 for i, n in enumerate(names)), 30,
                         "the robot at the sliders' start values")

    width = int(dict(line.split("=", 1) for line in xvfb.run("xdotool", "getwindowgeometry", "--shell", window)
                     .split() if "=" in line)["WIDTH"])
    x, y = wait_for(lambda: first_slider_groove(xvfb.screenshot(tmp_path / "gui.png"), width), 20,
                    "the GUI's sliders on screen", 0.5)
    xvfb.run("xdotool", "mousemove", "--window", window, str(x), str(y), "click", "1")  # focus (and one page step)
    xvfb.run("xdotool", "key", "End")  # the slider to its maximum: the joint's upper limit
    joints.wait(lambda s: abs(joint_q(s, names, SLIDER) - q_max[0]) < 0.1, 20,
                        f"{SLIDER} at its upper limit {q_max[0]:.3f}")
    moved = sent.history[first:]
    assert moved and all(t.names == (SLIDER,) for t in moved), "only the moved slider went to the bridge"
    assert abs(moved[-1].q[0] - q_max[0]) < 1e-6
    assert gui.proc.poll() is None, gui.log()


def robot_pixels(image: np.ndarray) -> np.ndarray:
    """Mask of the robot in the 3D view: grey pixels inside the box the background colour spans."""
    background = np.all(image == BACKGROUND, axis=-1)
    rows, cols = np.nonzero(background)
    if rows.size == 0:
        return np.zeros(image.shape[:2], bool)
    view = np.zeros(image.shape[:2], bool)
    view[rows.min():rows.max() + 1, cols.min():cols.max() + 1] = True
    spread = image.max(axis=-1).astype(int) - image.min(axis=-1)
    return view & ~background & (spread < 16)


def extent(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    return cols.min(), cols.max(), rows.min(), rows.max()


def test_gui_rviz_draws_the_robot_in_the_sims_pose(graph, tmp_path) -> None:
    stack, xvfb, tool = graph
    names = ctl(stack.session, KEYS.robot_info)["joint_names"]
    joints = Latest(stack.session, KEYS.joints, JointState)
    tool(RSP, "joint_states:=/g1_description/joint_states")
    rviz = tool("rviz", "-d", str(RVIZ_CONFIG))

    def drawn(path):
        image = xvfb.screenshot(path)
        mask = robot_pixels(image)
        return (image, mask) if mask.sum() > 5000 else None

    image, mask = wait_for(lambda: drawn(tmp_path / "rviz-standing.png"), 90, "RViz to draw the robot", 1.0)
    left, right, top, bottom = extent(mask)
    height = bottom - top
    assert 300 < height < 700, f"a robot {height} pixels tall: not the G1 in the default view"

    # Raise the left arm sideways in the sim: RViz must draw it out there.
    stack.session.put(KEYS.joint_target("left_shoulder_roll_joint"), "1.5")
    joints.wait(lambda s: abs(joint_q(s, names, "left_shoulder_roll_joint") - 1.5) < 0.05, 20, "the arm raised")

    def widened(path):
        found = drawn(path)
        if found is None:
            return None
        l2, r2, _, _ = extent(found[1])
        return found if (r2 - l2) > 1.4 * (right - left) else None

    raised, raised_mask = wait_for(lambda: widened(tmp_path / "rviz-arm.png"), 30, "RViz to draw the raised arm", 1.0)
    l2, r2, t2, b2 = extent(raised_mask)
    grown_left, grown_right = left - l2, r2 - right
    assert max(grown_left, grown_right) > 5 * max(min(grown_left, grown_right), 1), "one arm, one side"
    assert abs(b2 - bottom) < 10, "the feet stay where the fixed base holds them"
    assert rviz.proc.poll() is None, rviz.log()
    shutil.copy(tmp_path / "rviz-arm.png", tmp_path / "rviz.png")
    print(f"[ros1] rviz screenshots in {tmp_path}: robot {height} px tall; raised arm widened it "
          f"{right - left} -> {r2 - l2} px")
