"""`zensim viz` as users run it: real sim, bridge and viz processes, real Zenoh, a real headless chromium.

The sim runs in the fixed mode (gravity off, base welded) so joints track
their targets closely and nothing falls over while the page is checked.
Software WebGL is slow here (a few fps), so waits are on conditions the page
reports (`window.zensim`), never on fixed sleeps.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable

import numpy as np
import pytest
import zenoh

from browser import Browser, decode_png
from support import REPO, Latest, Service, free_port, wait_for
from zensim.schemas import Codec, JointState, Keys, SimStatus

PANEL_WIDTH_PX = 320
JOINT = "left_elbow_joint"
DISTAL_LINK = "left_wrist_yaw_link"
GHOST_OFFSET_M = (0.0, 0.9, 0.0)
"""The viz's default ghost_offset_m: the ghost stands beside the robot."""
SCREENSHOT = REPO / "docs" / "screenshot.png"


def alive(session: zenoh.Session, keys: Keys) -> set[str]:
    return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in session.liveliness().get(keys.alive_any, timeout=1.0) if r.ok}


class Stack:
    """sim + bridge + viz for one test, with the viz restartable on the same port."""

    def __init__(self, start: Callable[..., Service], session: zenoh.Session, robot_id: str) -> None:
        self.start = start
        self.session = session
        self.keys = Keys(robot_id)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}/"
        self.sim = start("sim", "--mode", "fixed")
        self.bridge = start("bridge")
        self.viz = self.start_viz()
        wait_for(lambda: {"sim", "bridge", "viz"} <= alive(session, self.keys), 30, "sim, bridge and viz alive")

    def start_viz(self) -> Service:
        return self.start("viz", "--port", str(self.port))


@pytest.fixture
def stack(start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str) -> Stack:
    return Stack(start_service, zsession, robot_id)


def open_page(browser: Browser, url: str, generation: int = 1) -> None:
    browser.goto(url)
    browser.wait(f"window.zensim && zensim.sceneReady && zensim.generation >= {generation}", 60, "the robot drawn")


def robot_pixels(rgb: np.ndarray) -> np.ndarray:
    """Mask of the URDF colours as lit: neutral greys (dark 0.2 and white 0.7 materials).

    meshcat's background is a blue gradient, so grey pixels in the 3D area
    are the robot (and the thin grid lines, which a second, robot-hidden
    screenshot subtracts).
    """
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    neutral = (abs(r - g) < 14) & (abs(g - b) < 14) & (abs(r - b) < 14)
    return neutral & (r > 25) & (r < 235)


class TestVizPage:
    def test_page_shows_robot_and_panel(self, stack: Stack, browser: Browser) -> None:
        open_page(browser, stack.url)
        browser.wait("zensim.status && ['sim','bridge','viz'].every(s => zensim.status.alive.includes(s))", 20,
                     "the panel showing sim, bridge and viz alive")
        browser.wait("zensim.status.sim && zensim.status.sim.sim_time_s > 0", 20, "sim time on the panel")
        assert browser.eval("document.querySelectorAll('#sliders input[type=range]').length") == 29
        for verb in ("reset", "pause", "resume", "step"):
            assert browser.eval(f"!!document.getElementById('btn-{verb}')")
        assert browser.eval("document.getElementById('mode').value") == "fixed"
        # The bundled G1 is drawn with its shells: every visual mesh it names, fetched from the sim.
        shells = len(list((REPO / "robots" / "unitree_g1" / "meshes").glob("*.STL")))
        assert f", {shells} meshes (" in stack.viz.log() and shells >= 30, stack.viz.log()[-2000:]
        # Let a few frames draw after the status panel filled, then take the picture.
        frames = browser.eval("zensim.framesApplied")
        browser.wait(f"zensim.framesApplied > {frames + 2}", 30, "more frames drawn")
        png = browser.screenshot()
        shot = decode_png(png)
        height, width, _ = shot.shape
        view = shot[:, : width - PANEL_WIDTH_PX]
        with_robot = robot_pixels(view)

        browser.eval("(() => { for (const r of ['robot','ghost']) viewer.set_property([r], 'visible', false);"
                     " viewer.set_dirty(); return true; })()")
        browser.eval("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))")
        without = robot_pixels(decode_png(browser.screenshot())[:, : width - PANEL_WIDTH_PX])
        robot_only = with_robot & ~without
        share = robot_only.mean()
        assert share > 0.01, f"only {share:.4f} of the 3D view shows the robot's colours"
        dark = (view[..., 0] < 90) & robot_only
        assert dark.sum() > 100, "the URDF's dark material (head, feet) is not drawn"
        panel = shot[:, width - PANEL_WIDTH_PX:]
        panel_bg = (abs(panel.astype(int) - np.array([0x2A, 0x2F, 0x37])).sum(axis=2) < 12).mean()
        assert panel_bg > 0.3, "the panel is not drawn"
        if os.environ.get("ZENSIM_SAVE_SCREENSHOT"):
            SCREENSHOT.parent.mkdir(exist_ok=True)
            SCREENSHOT.write_bytes(png)

    def test_slider_moves_sim_and_ghost(self, stack: Stack, browser: Browser) -> None:
        open_page(browser, stack.url)
        info_names = browser.eval("zensim.robot.joints.map(j => j.name)")
        index = info_names.index(JOINT)
        latest: dict[str, JointState] = {}
        codec = Codec(JointState)
        sub = stack.session.declare_subscriber(
            stack.keys.joints, lambda s: latest.__setitem__("js", codec.decode(s.payload.to_bytes())))
        try:
            wait_for(lambda: "js" in latest, 10, "joint states")
            start_q = latest["js"].q[index]
            target = 1.2 if start_q < 0.6 else 0.0
            before = browser.eval(f"zensim.linkPosition('ghost', '{DISTAL_LINK}')")
            browser.set_slider(f"slider-{JOINT}", target)
            wait_for(lambda: abs(latest["js"].q[index] - target) < 0.05, 15, f"the sim's {JOINT} at {target}")
        finally:
            sub.undeclare()
        browser.wait(
            f"zensim.status.targets && Math.abs(zensim.status.targets.q[zensim.status.targets.names"
            f".indexOf('{JOINT}')] - {target}) < 1e-3", 10, "the bridge's target on the page")

        def ghost_on_target() -> bool:
            ghost = browser.eval(f"zensim.linkPosition('ghost', '{DISTAL_LINK}')")
            robot = browser.eval(f"zensim.linkPosition('robot', '{DISTAL_LINK}')")
            return bool(np.linalg.norm(np.subtract(ghost, before)) > 0.05
                        and np.linalg.norm(np.subtract(ghost, GHOST_OFFSET_M) - robot) < 0.03)

        wait_for(ghost_on_target, 20, "the ghost's hand moved to the target and the robot's hand with it",
                 interval_s=0.3)
        assert browser.eval("zensim.lastError") is None

    def test_panel_buttons_pause_step_resume_switch_mode_and_reset(self, stack: Stack, browser: Browser) -> None:
        open_page(browser, stack.url)
        status = Latest(stack.session, stack.keys.sim_status, SimStatus)
        joints = Latest(stack.session, stack.keys.joints, JointState)
        status.wait(what="the sim's status")

        def clicked(verb: str) -> None:
            browser.eval("(zensim.lastReply = null, true)")
            browser.click(f"btn-{verb}")
            reply = browser.wait(f"zensim.lastReply && zensim.lastReply.verb === '{verb}' && zensim.lastReply", 10,
                                 f"the reply to {verb} on the page")
            assert reply["ok"], reply

        clicked("pause")
        paused = status.wait(lambda m: m.paused, what="the sim paused")
        browser.wait("document.getElementById('sim-state').textContent.startsWith('paused')", 10, "'paused' shown")
        before = joints.wait(lambda m: m.sim_time_s >= paused.sim_time_s).sim_time_s
        clicked("step")
        joints.wait(lambda m: m.sim_time_s == pytest.approx(before + paused.timestep_s, abs=1e-9),
                    what="exactly one physics step")
        clicked("resume")
        status.wait(lambda m: not m.paused and m.sim_time_s > before + 0.1, what="the sim running again")

        resets = status.value.resets
        browser.select("mode", "floating")
        status.wait(lambda m: m.mode == "floating", what="the sim in the floating mode")
        browser.wait("document.getElementById('sim-state').textContent.includes('floating')", 10, "'floating' shown")
        clicked("reset")
        status.wait(lambda m: m.resets >= resets + 2, what="the mode switch and the reset counted")
        assert browser.eval("zensim.lastError") is None

    def test_page_comes_back_after_viz_restart(self, stack: Stack, browser: Browser) -> None:
        open_page(browser, stack.url)
        t0 = time.monotonic()
        stack.viz.signal(signal.SIGTERM)
        code = stack.viz.proc.wait(5)
        took = time.monotonic() - t0
        assert code == 0 and took < 2.0, f"viz exited {code} after {took:.2f} s"
        wait_for(lambda: "viz" not in alive(stack.session, stack.keys), 5, "alive/viz gone")
        browser.wait("!zensim.connected", 10, "the page to notice")
        stack.viz = stack.start_viz()
        browser.wait("zensim.connected && zensim.connects >= 2 && zensim.sceneReady", 60,
                     "the page to reconnect and draw the robot again by itself")

    def test_description_fetched_again_after_sim_restart(self, stack: Stack, browser: Browser) -> None:
        open_page(browser, stack.url)
        generation = browser.eval("zensim.generation")
        stack.sim.kill()
        wait_for(lambda: "sim" not in alive(stack.session, stack.keys), 5, "alive/sim gone")
        stack.sim = stack.start("sim", "--mode", "fixed")
        browser.wait(f"zensim.generation > {generation} && zensim.sceneReady", 60,
                     "a new drawing after the sim came back")
        assert stack.viz.log().count("description of g1_29dof") >= 2
