"""ctl requests with `at_s` (services/sim/schedule.py): they act at the step that starts at their sim time.

Under lockstep a ctl/push sent "now" lands at whichever advance the sim's loop reaches first; one with `at_s`
lands at its own step, whenever it was sent. The lockstep checks are exact: a push starts at the step it
asked for (in the middle of an advance of 10 steps), faults are set at theirs; a time already past, a request
with nothing to do, NaN or absurd times are refused whole and counted; a reset drops what waited.
"""

from __future__ import annotations

import math

import pytest

from support import Latest, ctl
from test_disturbances_process import limp
from test_lockstep_process import advance
from test_sim_process import robot_info, wait_alive
from zensim.loco.velocities import ScheduledVelocities
from zensim.schemas import Keys, PushRequest, SimStatus, VelocityCommand
from zensim.schemas.messages import MAX_SCHEDULED
from zensim.sim.schedule import NO_STEP, Schedule, ScheduleError

DT = 0.002


def test_requests_run_before_the_step_that_starts_at_their_time_in_the_order_they_came() -> None:
    schedule, ran = Schedule(), []
    assert schedule.add(0, at_s=0.106, now_s=0.1, step=50, timestep_s=DT, run=lambda: ran.append("push")) == 53
    assert schedule.add(1, at_s=0.1, now_s=0.1, step=50, timestep_s=DT, run=lambda: ran.append("now")) == 50
    # A time read off a state is a sum of floats: 0.1 + 3 x 0.002 may be 0.10600000000000001, still step 53.
    assert schedule.add(0, at_s=0.1 + 3 * DT, now_s=0.1, step=50, timestep_s=DT, run=lambda: ran.append("2nd")) == 53
    assert schedule.add(0, at_s=0.1061, now_s=0.1, step=50, timestep_s=DT, run=lambda: ran.append("54")) == 54
    assert schedule.next_step == 50 and schedule.waiting(0) == 3 and schedule.waiting(1) == 1
    schedule.run_due(52)
    assert ran == ["now"] and schedule.next_step == 53
    schedule.run_due(53)
    assert ran == ["now", "push", "2nd"]
    schedule.drop(0)
    assert schedule.next_step == NO_STEP and schedule.waiting(0) == 0
    schedule.run_due(1000)
    assert ran == ["now", "push", "2nd"], "a dropped request never runs"


def test_a_time_past_and_one_request_too_many_are_refused() -> None:
    schedule = Schedule()
    with pytest.raises(ScheduleError, match="has passed"):
        schedule.add(0, at_s=0.09, now_s=0.1, step=50, timestep_s=DT, run=lambda: None)
    for _ in range(MAX_SCHEDULED):
        schedule.add(0, at_s=1.0, now_s=0.1, step=50, timestep_s=DT, run=lambda: None)
    with pytest.raises(ScheduleError, match="already wait"):
        schedule.add(0, at_s=1.0, now_s=0.1, step=50, timestep_s=DT, run=lambda: None)
    schedule.add(1, at_s=1.0, now_s=0.1, step=50, timestep_s=DT, run=lambda: None)  # another robot's own bound


@pytest.mark.parametrize("at_s", [math.nan, math.inf, -1.0, 1e300])
def test_a_push_at_an_absurd_time_does_not_decode(at_s: float) -> None:
    with pytest.raises(ValueError, match="at_s"):
        PushRequest(direction=(1.0, 0.0, 0.0), magnitude_n=10.0, duration_s=0.1, at_s=at_s)


def test_lockstep_scheduled_push_and_faults_act_at_their_own_step_and_a_reset_drops_the_rest(
        start_service, zsession, robot_id) -> None:
    keys = Keys(robot_id)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--clock", "lockstep", "--band", "true")
    wait_alive(zsession, keys)
    n = len(robot_info(zsession, keys)["joint_names"])
    # Sent while the sim waits at 0 s: a push at 0.106 s (step 53, inside the advance from 0.10 to 0.12 s),
    # faults at 0.2 s, a band length at 0.3 s.
    push = {"direction": [0, 1, 0], "magnitude_n": 100, "duration_s": 0.004, "at_s": 0.106}
    pushed = ctl(zsession, keys.ctl("push"), push)
    assert pushed["ok"] and pushed["scheduled_at_s"] == pytest.approx(0.106, abs=1e-12), pushed
    assert pushed["push"]["start_s"] == pytest.approx(0.106, abs=1e-12) and pushed["push"]["remaining_s"] == 0.004
    faults = ctl(zsession, keys.ctl("faults"), {"verb": "set", "seed": 3, "at_s": 0.2,
                                               "joints": [{"joint": "left_knee_joint", "torque_scale": 0.5}]})
    assert faults["ok"] and faults["faults"] is None and faults["scheduled_at_s"] == pytest.approx(0.2), faults
    band = ctl(zsession, keys.ctl("band"), {"length_m": 2.0, "at_s": 0.3})
    assert band["ok"] and band["band"]["length_m"] == 0.0, "the band keeps its length until its time"
    status.wait(lambda s: s.scheduled == 3, what="three requests waiting in state/sim")

    for _ in range(5):
        state = advance(zsession, keys, limp(n))
    assert state["sim_time_s"] == pytest.approx(0.1, abs=1e-9)
    assert status.wait(lambda s: s.steps == 50, what="0.1 s").pushes_applied == 0, "not before its time"
    advance(zsession, keys, limp(n))  # 0.10 -> 0.12 s: the push acts for steps 53 and 54
    seen = status.wait(lambda s: s.steps == 60, what="0.12 s")
    assert seen.pushes_applied == 1 and seen.last_push is not None and seen.scheduled == 2
    assert seen.last_push.start_s == pytest.approx(0.106, abs=1e-12) and seen.pushes == ()
    for _ in range(5):
        advance(zsession, keys, limp(n))  # to 0.22 s
    seen = status.wait(lambda s: s.steps == 110, what="0.22 s")
    assert seen.faults is not None and seen.faults.set_at_s == pytest.approx(0.2, abs=1e-12) and seen.scheduled == 1
    assert seen.faults.joints[0].torque_scale == 0.5

    # A time already past, a request that does nothing at its time, NaN: refused whole, counted, nothing waits.
    before = seen.rejected_requests
    late = ctl(zsession, keys.ctl("push"), {**push, "at_s": 0.1})
    assert not late["ok"] and "has passed" in late["error"] and late["sim_time_s"] == pytest.approx(0.22)
    assert not ctl(zsession, keys.ctl("faults"), {"at_s": 1.0})["ok"]
    assert "at_s" in ctl(zsession, keys.ctl("band"), {"at_s": 1.0})["error"]
    assert not ctl(zsession, keys.ctl("push"), {**push, "at_s": float("nan")})["ok"]
    assert "tail" in ctl(zsession, keys.ctl("push"), {**push, "at_s": 1.0, "body": "tail_link"})["error"]
    seen = status.wait(lambda s: s.rejected_requests == before + 5, what="five refusals counted")
    assert seen.scheduled == 1 and seen.pushes_applied == 1

    ctl(zsession, keys.ctl("reset"))
    seen = status.wait(lambda s: s.resets >= 1, what="the reset")
    assert seen.scheduled == 0, "a reset drops what waited for the last episode"
    for _ in range(20):
        advance(zsession, keys, limp(n))
    seen = status.wait(lambda s: s.steps == 200, what="0.4 s of the new episode")
    assert seen.band is not None and seen.band.length_m == 0.0, "the dropped band request never acted"


def test_the_walking_controller_keeps_timed_velocities_for_their_tick_in_order_and_bounded() -> None:
    waiting = ScheduledVelocities()
    for at_s, vx in ((3.0, 0.3), (1.0, 0.1), (1.0, 0.2), (2.0 + 1e-12, 0.25)):
        assert waiting.add(VelocityCommand(vx=vx, at_s=at_s))
    assert waiting.due(0.98) == []
    assert [c.vx for c in waiting.due(1.0)] == [0.1, 0.2], "one time: first come, first served"
    assert [c.vx for c in waiting.due(2.0)] == [0.25], "a time read off a state is a sum of floats"
    assert len(waiting) == 1
    waiting.clear()
    assert waiting.due(10.0) == []
    for _ in range(MAX_SCHEDULED):
        assert waiting.add(VelocityCommand(vx=0.1, at_s=5.0))
    assert not waiting.add(VelocityCommand(vx=0.1, at_s=5.0)), "one more than the bound is not kept"
