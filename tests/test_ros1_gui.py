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
from support import REPO, Latest, ctl, wait_for
from zensim.schemas import JointState, JointTargets, Keys, Odometry, Ros1Status

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


@pytest.fixture(params=[("--mode", "fixed")])
def graph(tmp_path, request):
    """A roscore, the G1 with bridge and gateway, an X server. By default the fixed-base G1 (gravity off:
    any pose holds); `@pytest.mark.parametrize("graph", [()], indirect=True)` for the floating one."""
    core = Roscore(tmp_path / "ros")
    stack = Stack(core, tmp_path, sim_args=tuple(request.param))
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


def window_image(xvfb: Xvfb, window: str, path) -> np.ndarray:
    """One window raised to the top and captured alone (RViz fills the screen; the GUI sits over it)."""
    from PIL import Image

    xvfb.run("xdotool", "windowraise", window)
    xvfb.run("import", "-window", window, str(path))
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


@pytest.mark.parametrize("graph", [()], indirect=True)
def test_gui_display_launch_draws_the_standing_floating_g1_and_its_sliders_move_it(graph, tmp_path) -> None:
    """`roslaunch deploy/ros1/display.launch` as shipped, beside the floating G1 (the seed's workflow): the GUI's
    first message sets every joint to 0 and the G1 stands up straight instead of falling (the bridge moves
    every joint of it together); RViz draws it standing; a slider moved with real key presses moves the joint."""
    stack, xvfb, tool = graph
    info = ctl(stack.session, KEYS.robot_info)
    names, q_min, q_max = info["joint_names"], info["q_min"], info["q_max"]
    assert names[0] == SLIDER
    joints = Latest(stack.session, KEYS.joints, JointState)
    odom = Latest(stack.session, KEYS.odom, Odometry)
    sent = Latest(stack.session, KEYS.joint_targets, JointTargets)
    sent.keep_history = True
    heights: list[float] = []
    watch = stack.session.declare_subscriber(KEYS.odom, lambda _: heights.append(odom.value.pos[2]) if odom.value else None)
    launch = tool("roslaunch", str(REPO / "deploy" / "ros1" / "display.launch"))
    gui = wait_for(lambda: xvfb.window("^Node: "), 90, "the GUI's window", 0.5)
    wait_for(lambda: sent.history, 30, "the GUI's first message")
    first = sent.history[0]  # the sliders' start values: 0 to their resolution (1/10000 of each range)
    assert sorted(first.names) == sorted(names) and max(map(abs, first.q)) < 1e-3, "every joint to 0"
    # Standing straight (0.79 m; the squat is 0.73 m) and never down on the way.
    odom.wait(lambda o: o.pos[2] > 0.77, 20, "the G1 standing up straight")
    settled = len(heights)
    wait_for(lambda: len(heights) > settled + 200, 20, "two more seconds of odometry")
    assert min(heights) > 0.6, f"the pelvis went down to {min(heights):.2f} m"

    rviz = wait_for(lambda: xvfb.window("RViz"), 90, "RViz's window", 0.5)

    def standing_drawn():
        mask = robot_pixels(window_image(xvfb, rviz, tmp_path / "display-rviz.png"))
        if mask.sum() < 5000:
            return None
        left, right, top, bottom = extent(mask)
        return (left, right, top, bottom) if 300 < bottom - top < 750 and right - left < 0.5 * (bottom - top) else None

    # No window manager: the GUI sits over RViz's 3D view, which repaints the uncovered part at its own
    # slow pace (software GL): wait for a frame with the G1 alone, standing (much taller than wide).
    xvfb.run("xdotool", "windowunmap", gui)
    left, right, top, bottom = wait_for(standing_drawn, 120, "RViz to draw the standing G1", 1.0)
    xvfb.run("xdotool", "windowmap", gui)

    # The first slider (left_hip_pitch_joint): a click in its groove right of the handle (one page step, 10 of
    # 10000) gives it the focus, then 300 presses of Right (one step each): +310/10000 of its range.
    width = int(dict(line.split("=", 1) for line in xvfb.run("xdotool", "getwindowgeometry", "--shell", gui)
                     .split() if "=" in line)["WIDTH"])
    x, y = wait_for(lambda: first_slider_groove(window_image(xvfb, gui, tmp_path / "display-gui.png"), width), 20,
                    "the GUI's sliders on screen", 0.5)
    before = len(sent.history)
    xvfb.run("xdotool", "mousemove", "--window", gui, str(x), str(y), "click", "1")
    xvfb.run("xdotool", "key", "--repeat", "300", "--delay", "2", "Right", timeout_s=60)
    expected = first.q[first.names.index(SLIDER)] + 310 / 10000 * (q_max[0] - q_min[0])
    wait_for(lambda: len(sent.history) > before and abs(sent.history[-1].q[0] - expected) < 0.01, 20,
             "the GUI to send the slider's new value")
    moved = sent.history[before:]
    assert all(t.names == (SLIDER,) for t in moved), "only the moved slider went to the bridge"
    joints.wait(lambda s: abs(joint_q(s, names, SLIDER) - expected) < 0.05, 20, f"{SLIDER} at {expected:.3f}")
    watch.undeclare()
    assert launch.proc.poll() is None, launch.log()[-3000:]
    print(f"[ros1] display.launch: standing at {heights[-1]:.3f} m (lowest {min(heights):.3f} m), RViz drew it "
          f"{bottom - top} px tall, the slider moved {SLIDER} to {expected:.3f} rad")
