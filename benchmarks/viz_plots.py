"""Does the plot panel slow the 3D view? Frames drawn per second with the plots hidden, shown, hidden again.

    .venv/bin/python benchmarks/viz_plots.py [--seconds 10] [--joints 3]

Starts a router, a sim (fixed G1), a bridge and a viz as real processes on loopback and one headless
chromium (software WebGL, as the tests use), opens the page and counts `zensim.framesApplied` (pose
frames the page drew) over `--seconds` in each phase; with the plots shown it also counts plotly
redraws. Software WebGL is the bottleneck here, so the figure is the browser's own limit: the test is
whether showing the plots lowers it, and how much of the page's main thread a plotly redraw takes
(`zensim.plot.redrawMs`), which is less noisy on a shared machine than frame rates.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from harness import Processes, free_port, test_scaffolding

Browser = test_scaffolding("browser").Browser

JOINTS = ["left_elbow_joint", "right_knee_joint", "left_shoulder_pitch_joint", "right_elbow_joint",
          "left_knee_joint", "waist_yaw_joint"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each phase, s")
    parser.add_argument("--joints", type=int, default=3, help="joints plotted (1-6)")
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1", ZENSIM_ROBOT_ID="plotbench",
               ZENSIM_LOG_LEVEL="WARNING")
    procs = Processes(dict(env, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint), prefix="viz-plots-bench-")
    port = free_port()
    try:
        procs.zensim("router", "--zenoh-listen", endpoint, "--zenoh-mode", "router", "--zenoh-connect", "")
        procs.zensim("sim", "--mode", "fixed")
        procs.zensim("bridge")
        procs.zensim("viz", "--port", str(port))
        with Browser(1280, 800) as browser:
            browser.wait("true", 5)
            time.sleep(3)  # the services find each other
            browser.goto(f"http://127.0.0.1:{port}/")
            browser.wait("window.zensim && zensim.sceneReady", 60, "the robot drawn")

            def frames_per_s() -> float:
                f0, t0 = browser.eval("zensim.framesApplied"), time.monotonic()
                time.sleep(args.seconds)
                return (browser.eval("zensim.framesApplied") - f0) / (time.monotonic() - t0)

            hidden_before = frames_per_s()
            chosen = JOINTS[: max(1, min(6, args.joints))]
            browser.eval(f"(() => {{ const s = document.getElementById('plot-joints'); const want = {chosen!r};"
                         " for (const o of s.options) o.selected = want.includes(o.value);"
                         " s.dispatchEvent(new Event('change')); return true; })()")
            browser.click("btn-plot")
            browser.wait("zensim.plot.redraws > 2", 60, "the plots drawn")
            r0, ms0 = browser.eval("[zensim.plot.redraws, zensim.plot.redrawMs]")
            shown = frames_per_s()
            r1, ms1 = browser.eval("[zensim.plot.redraws, zensim.plot.redrawMs]")
            redraws = (r1 - r0) / args.seconds
            redraw_ms = (ms1 - ms0) / max(1, r1 - r0)
            browser.click("btn-plot")
            time.sleep(1.0)
            hidden_after = frames_per_s()
    finally:
        procs.stop_all()
    print(f"3D frames drawn per second (headless chromium, software WebGL), {args.seconds:.0f} s each:")
    print(f"  plots hidden {hidden_before:.1f} | plots shown ({len(chosen)} joints) {shown:.1f} "
          f"(plotly redraws {redraws:.1f}/s) | hidden again {hidden_after:.1f}")
    print(f"  one plotly redraw: {redraw_ms:.1f} ms of the page's main thread, {redraw_ms * redraws / 10:.1f} % of it")
    print(f"logs: {procs.dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
