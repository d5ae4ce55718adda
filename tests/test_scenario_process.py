"""`zensim scenario FILE` and `zensim course` as users run them: real sims, `zensim loco`, a plain client.

Lockstep throughout: the walking controller (or the user's) is the clock, so sim time moves at the pace
of its commands whatever loads the machine, and the scenario's events land on sim time.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from support import wait_for
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
