"""The viewer's plot panel in a real headless chromium: joint position vs target and torque, and RTF, drawn by plotly.js."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from browser import Browser, decode_png
from support import Latest
from test_viz_process import JOINT, Stack, open_page, stack  # noqa: F401 - fixtures
from zensim.schemas import JointState
from zensim.viz import panel, plots

SECOND_JOINT = "right_knee_joint"
COLOURS = {"first": (0x4E, 0x9C, 0xFF), "second": (0xFF, 0x9F, 0x40), "rtf": (0xE3, 0x77, 0xC2)}


def rect(browser: Browser, element_id: str) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) of an element, in screenshot pixels."""
    left, top, right, bottom = (int(round(v)) for v in browser.eval(
        f"(() => {{ const r = document.getElementById('{element_id}').getBoundingClientRect();"
        " return [r.left, r.top, r.right, r.bottom]; })()"))
    return left, top, right, bottom


def colour_pixels(shot: np.ndarray, box: tuple[int, int, int, int], colour: tuple[int, int, int], tol: int = 40) -> int:
    left, top, right, bottom = box
    area = shot[top:bottom, left:right].astype(int)
    return int((np.abs(area - np.array(colour)).max(axis=2) < tol).sum())


def choose(browser: Browser, *joints: str) -> None:
    """Pick joints in the multi-select as a user does (ctrl-click ends in the same state and event)."""
    names = ",".join(f"'{j}'" for j in joints)
    browser.eval(f"(() => {{ const s = document.getElementById('plot-joints'); const want = [{names}];"
                 " for (const o of s.options) o.selected = want.includes(o.value);"
                 " s.dispatchEvent(new Event('change', {bubbles: true})); return true; })()")


def test_plot_panel_draws_the_selected_joints_curves(stack: Stack, browser: Browser) -> None:
    open_page(browser, stack.url)
    assert browser.eval("document.getElementById('plots').hidden") is True
    choose(browser, JOINT, SECOND_JOINT)
    browser.click("btn-plot")
    browser.wait("window.Plotly && zensim.plot.redraws > 0 && zensim.plot.t.length > 50", 60, "plots drawn with data")
    # Move the elbow: the actual curve goes to the target the bridge commands.
    joints = Latest(stack.session, stack.keys.joints, JointState)
    joints.wait(what="joint states")
    browser.set_slider(f"slider-{JOINT}", 1.2)
    # Joints are plotted in the robot's order (legs before arms), each in its own colour.
    assert browser.eval("zensim.plot.joints") == [SECOND_JOINT, JOINT]
    browser.wait("(() => { const p = zensim.plot; const n = p.t.length - 1;"
                 " return n > 0 && Math.abs(p.target[1][n] - 1.2) < 0.01 && Math.abs(p.q[1][n] - 1.2) < 0.05; })()",
                 30, "the plotted elbow position and target at 1.2")
    assert browser.eval("zensim.plot.rtf.length") > 3
    redraws = browser.eval("zensim.plot.redraws")
    browser.wait(f"zensim.plot.redraws > {redraws + 1}", 10, "the plots redrawn with the move")
    # The sim time axis spans at most the 10 s window.
    span = browser.eval("zensim.plot.t[zensim.plot.t.length - 1] - zensim.plot.t[0]")
    assert 0 < span <= 10.0 + 1e-6

    png = browser.screenshot()
    if os.environ.get("ZENSIM_SAVE_PLOT_SCREENSHOT"):
        Path(os.environ["ZENSIM_SAVE_PLOT_SCREENSHOT"]).write_bytes(png)
    shot = decode_png(png)
    chart = rect(browser, "plot-joints-chart")
    left, top, right, bottom = chart
    upper = (left, top, right, top + (bottom - top) // 2)     # position subplot
    lower = (left, top + (bottom - top) * 2 // 3, right, bottom)  # torque subplot: the elbow's move shows
    rtf_chart = rect(browser, "plot-rtf-chart")
    with_plots = {
        "first upper": colour_pixels(shot, upper, COLOURS["first"]),
        "second lower": colour_pixels(shot, lower, COLOURS["second"]),
        "second upper": colour_pixels(shot, upper, COLOURS["second"]),
        "rtf": colour_pixels(shot, rtf_chart, COLOURS["rtf"]),
    }
    # Same regions with the panel hidden: what the 3D view alone has of these colours.
    browser.click("btn-plot")
    browser.wait("document.getElementById('plots').hidden", 5, "the plots hidden")
    browser.eval("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))")
    hidden = decode_png(browser.screenshot())
    without = {
        "first upper": colour_pixels(hidden, upper, COLOURS["first"]),
        "second lower": colour_pixels(hidden, lower, COLOURS["second"]),
        "second upper": colour_pixels(hidden, upper, COLOURS["second"]),
        "rtf": colour_pixels(hidden, rtf_chart, COLOURS["rtf"]),
    }
    for part in with_plots:
        assert with_plots[part] - without[part] > 60, f"{part}: {with_plots} vs hidden {without}"
    assert browser.eval("zensim.lastError") is None


class TestPlotFeed:
    """The plot data without a browser: requests checked, samples thinned, resets and batches."""

    NAMES = ("a", "b", "c")

    def test_plot_requests_are_checked(self) -> None:
        limits = panel.JointLimits(self.NAMES, (-1, -1, -1), (1, 1, 1))
        assert panel.parse_client_message({"type": "plot", "joints": ["b"]}, limits) == panel.PlotRequest(("b",))
        assert panel.parse_client_message({"type": "plot", "joints": []}, None) == panel.PlotRequest(())
        for bad in (["x"], "a", ["a", "a"], ["a"] * 7, [1]):
            with pytest.raises(panel.PanelError):
                panel.parse_client_message({"type": "plot", "joints": bad}, limits)
        with pytest.raises(panel.PanelError):
            panel.parse_client_message({"type": "plot", "joints": ["a"]}, None)

    def test_batches_carry_only_the_chosen_joints_and_only_new_samples(self) -> None:
        feed = plots.PlotFeed()
        feed.set_joints(self.NAMES)
        sub = feed.subscribe(["c", "a"])
        feed.on_command(None, (0.1, 0.2, 0.3))
        feed.on_state(0.0, (1.0, 2.0, 3.0), (10.0, 20.0, 30.0))
        feed.on_command(("a",), (0.5,))
        feed.on_state(0.005, (9.0, 9.0, 9.0), (9.0, 9.0, 9.0))  # thinned: under 10 ms after the last
        feed.on_state(0.01, (1.5, 2.5, 3.5), (11.0, 21.0, 31.0))
        batch = feed.batch(sub)
        assert batch["clear"] is True and batch["joints"] == ["c", "a"] and batch["t"] == [0.0, 0.01]
        assert batch["q"] == [[3.0, 3.5], [1.0, 1.5]]
        assert batch["target"] == [[0.3, 0.3], [0.1, 0.5]]
        assert batch["tau"] == [[30.0, 31.0], [10.0, 11.0]]
        assert feed.batch(sub) is None
        feed.on_state(0.02, (0, 0, 0), (0, 0, 0))
        assert feed.batch(sub)["t"] == [0.02]
        feed.on_state(0.0, (0, 0, 0), (0, 0, 0))  # a reset: time starts over, pages clear
        again = feed.batch(sub)
        assert again["clear"] is True and again["t"] == [0.0]

    def test_window_is_bounded(self) -> None:
        feed = plots.PlotFeed()
        feed.set_joints(self.NAMES)
        for k in range(5000):
            feed.on_state(k * 0.01, (0, 0, 0), (0, 0, 0))
        batch = feed.batch(feed.subscribe(["a"]))
        assert len(batch["t"]) == plots.MAX_SAMPLES
        assert batch["t"][-1] - batch["t"][0] >= plots.WINDOW_S
