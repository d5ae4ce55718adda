"""Time to the first full frame of the default stack in chromium, with the G1's shells and without.

    .venv/bin/python benchmarks/first_paint.py [--trials 5] [--screenshot docs/screenshot.png]

Runs `zensim up` (router, sim, bridge, viz on loopback, the default floating G1) once per variant,
all at the same time, and for each trial opens the page in a fresh headless chromium (a new
profile: nothing cached) and times `goto` -> the page's `zensim.sceneReady` (the robot's scene
built, a pose applied and the next animation frame drawn: the first full frame). Trials alternate
between the variants so that each sees the same machine load. Variants:

- shells:     the bundled G1 as shipped (Unitree's decimated meshes as visuals);
- primitives: the same URDF with each visual replaced by its link's collision primitive (how the
              bundled G1 was drawn before it shipped the meshes);
- official:   Unitree's own URDF with its full 19 MB of meshes, when ZENSIM_OFFICIAL_G1 names a
              g1_description folder.

Also printed: what the viz fetched from the sim for each (its log's "N meshes (kB) in s").
--screenshot writes a PNG of the default stack's page (3D view and panel) once the panel shows
every service alive.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import tempfile
import time
from pathlib import Path

from harness import Processes, free_port, test_scaffolding, wait_for
from zensim.robots import robot_files

Browser = test_scaffolding("browser").Browser


def primitives_urdf(folder: Path) -> Path:
    """The bundled URDF drawn as its collision primitives (grey), written into `folder`."""
    text = robot_files("g1").urdf.read_text()
    text = re.sub(r"\n\s*<visual>.*?</visual>", "", text, flags=re.S)
    text = re.sub(r"<collision>(.*?)</collision>",
                  r'<visual>\1<material name="white"/></visual><collision>\1</collision>', text, flags=re.S)
    path = folder / "g1_primitives.urdf"
    path.write_text(text)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=5, help="page loads per variant")
    parser.add_argument("--screenshot", type=Path, help="write the default stack's page as a PNG here")
    parser.add_argument("--timeout-s", type=float, default=180.0, help="longest wait for one page's first frame")
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="zensim-first-paint-"))
    variants: dict[str, dict[str, str]] = {
        "shells": {},
        "primitives": {"ZENSIM_SIM_URDF": str(primitives_urdf(tmp)),
                       "ZENSIM_SIM_CONTROL": str(robot_files("g1").control)},
    }
    official = os.environ.get("ZENSIM_OFFICIAL_G1")
    if official:
        variants["official"] = {"ZENSIM_SIM_URDF": str(Path(official) / "g1_29dof.urdf"),
                                "ZENSIM_SIM_CONTROL": str(robot_files("g1").control)}
    procs = Processes(dict(os.environ, PYTHONUNBUFFERED="1"), prefix="zensim-first-paint-")
    urls, ups = {}, {}
    try:
        for name, extra in variants.items():
            port = free_port()
            # Each stack has its own router and no multicast scouting: the same robot id cannot mix them.
            env = dict(os.environ, PYTHONUNBUFFERED="1", ZENSIM_ROBOT_ID="g1",
                       ZENSIM_UP_ROUTER_ENDPOINT=f"tcp/127.0.0.1:{free_port()}", ZENSIM_VIZ_PORT=str(port), **extra)
            ups[name] = procs.zensim("up", env=env)
            urls[name] = f"http://127.0.0.1:{port}/"
        for name, up in ups.items():
            wait_for(lambda up=up: "description of" in up.log() or not up.alive(), 120, f"the {name} stack's viz")
            line = next(line for line in up.log().splitlines() if "description of" in line)
            print(f"{name}: viz {line.split('description of', 1)[1].strip()}")

        times: dict[str, list[float]] = {name: [] for name in variants}
        late = dict.fromkeys(variants, 0)
        for _ in range(args.trials):
            for name, url in urls.items():
                with Browser() as browser:
                    t0 = time.perf_counter()
                    browser.goto(url)
                    try:
                        browser.wait("window.zensim && zensim.sceneReady", args.timeout_s, f"the {name} robot drawn")
                    except AssertionError:
                        late[name] += 1
                        continue
                    times[name].append(time.perf_counter() - t0)
        for name, values in times.items():
            summary = (f"median {statistics.median(values):.2f} s, min {min(values):.2f} s, "
                       f"max {max(values):.2f} s (n={len(values)})") if values else "none"
            missed = f"; {late[name]} load(s) not drawn within {args.timeout_s:.0f} s" if late[name] else ""
            print(f"{name}: first full frame {summary}{missed}")

        if args.screenshot:
            with Browser() as browser:
                browser.goto(urls["shells"])
                browser.wait("window.zensim && zensim.sceneReady", 120, "the robot drawn")
                browser.wait("zensim.status && ['router','sim','bridge','viz'].every(s => zensim.status.alive.includes(s))"
                             " && zensim.status.sim && zensim.status.sim.sim_time_s > 3", 60, "the panel filled")
                frames = browser.eval("zensim.framesApplied")
                browser.wait(f"zensim.framesApplied > {frames + 2}", 30, "more frames drawn")
                args.screenshot.write_bytes(browser.screenshot())
                print(f"screenshot: {args.screenshot}")
    finally:
        procs.stop_all()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
