"""The page's messages: a msgspec tagged union, then the robot-aware checks (no browser, no zenoh)."""

from __future__ import annotations

import math

import pytest

from zensim.schemas import JointTargets, PushRequest
from zensim.viz import panel

LIMITS = panel.JointLimits(("knee", "elbow"), (-1.0, -2.0), (1.0, 2.0))


def test_each_message_type_becomes_its_command() -> None:
    targets = panel.parse_client_message({"type": "targets", "names": ["elbow"], "q": [3]}, LIMITS)
    assert targets == JointTargets(names=("elbow",), q=(2.0,)), "a target beyond the limit is clamped"
    assert panel.parse_client_message({"type": "ctl", "verb": "pause"}, LIMITS) == panel.Ctl("pause")
    assert panel.parse_client_message({"type": "mode", "mode": "fixed"}, None) == panel.Ctl("mode", "fixed")
    assert panel.parse_client_message({"type": "plot", "joints": ["knee"]}, LIMITS) == panel.PlotRequest(("knee",))
    assert panel.parse_client_message({"type": "band", "verb": "lower"}, None) == panel.Band("lower")
    push = panel.parse_client_message({"type": "push", "direction": "left"}, None)
    assert isinstance(push, panel.Push) and push.request == PushRequest(
        direction=(0.0, 1.0, 0.0), magnitude_n=panel.PUSH_MAGNITUDE_N, duration_s=panel.PUSH_DURATION_S)


@pytest.mark.parametrize("data", [{"type": "band", "verb": "on"}, {"type": "push", "direction": "forward"}])
def test_a_watching_page_may_not_use_the_band_or_push(data: dict) -> None:
    with pytest.raises(panel.PanelError, match="may watch, not drive"):
        panel.parse_client_message(data, LIMITS, may_drive=False)


@pytest.mark.parametrize("data", [
    [1, 2],                                                          # not an object
    {"verb": "pause"},                                               # no type
    {"type": "launch"},                                              # unknown type
    {"type": "ctl", "verb": "explode"},                              # unknown verb
    {"type": "ctl", "verb": "pause", "extra": 1},                    # unknown field
    {"type": "mode", "mode": "flying"},
    {"type": "targets", "names": ["knee"], "q": ["up"]},             # wrong type
    {"type": "targets", "names": ["knee"], "q": [True]},             # a bool is not a number
    {"type": "targets", "names": ["knee"], "q": [math.nan]},         # json.loads reads NaN
    {"type": "targets", "names": ["knee", "elbow"], "q": [0.1]},     # lengths differ
    {"type": "targets", "names": ["knee", "knee"], "q": [0.1, 0.2]},  # a joint twice
    {"type": "targets", "names": ["tail"], "q": [0.1]},              # unknown joint
    {"type": "targets", "names": [], "q": []},
    {"type": "plot", "joints": ["knee"] * 7},
    {"type": "band", "verb": "snap"},
    {"type": "band", "verb": "on", "length_m": 0.5},                 # the page's buttons send verbs only
    {"type": "push", "direction": "up"},
    {"type": "push", "direction": "forward", "magnitude_n": math.nan},
    {"type": "push", "direction": "forward", "magnitude_n": -80},
    {"type": "push", "direction": "forward", "duration_s": 60},      # a shove, not a constant force
    {"type": "push", "direction": [1, 0, 0]},
])
def test_anything_else_is_refused_with_a_reason(data: object) -> None:
    with pytest.raises(panel.PanelError) as info:
        panel.parse_client_message(data, LIMITS)
    assert str(info.value)


def test_targets_wait_for_a_robot_description() -> None:
    with pytest.raises(panel.PanelError, match="description"):
        panel.parse_client_message({"type": "targets", "names": ["knee"], "q": [0.1]}, None)


def test_a_long_unknown_name_is_not_echoed_whole() -> None:
    with pytest.raises(panel.PanelError) as info:
        panel.parse_client_message({"type": "targets", "names": ["x" * 100_000], "q": [0.1]}, LIMITS)
    assert len(str(info.value)) < 300


def test_a_running_viz_answers_hostile_page_messages_and_keeps_serving(start_service) -> None:
    """Raw websocket messages as a hostile page would send them, to a real `zensim viz`."""
    import asyncio
    import json as jsonlib

    import tornado.websocket

    from support import wait_for
    from test_viz_access import start_viz

    viz, port = start_viz(start_service)
    hostile = [
        "not json at all", "[" * 20_000 + "]" * 20_000, '{"type": "targets", "names": ["\\ud800"], "q": [0.1]}', '{"type": "targets", "names": ["x"], "q": [NaN]}',
        '{"type": "targets", "names": ["elbow"], "q": [1e300]}', jsonlib.dumps({"type": "targets", "names": ["j" * 60_000], "q": [0.1]}),
        '{"type": "ctl", "verb": "pause", "extra": 1}', "{}", "42",
    ]

    async def send_all() -> list[dict]:
        conn = await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{port}/ws")
        errors: list[dict] = []
        for message in hostile:
            await conn.write_message(message)
        while len(errors) < len(hostile):
            reply = await asyncio.wait_for(conn.read_message(), 10)
            if isinstance(reply, str) and jsonlib.loads(reply).get("type") == "error":
                errors.append(jsonlib.loads(reply))
        # Over the 64 KiB message cap: tornado closes this connection, the viz goes on.
        await conn.write_message("x" * 200_000)
        assert await asyncio.wait_for(conn.read_message(), 10) is None, "the oversize message did not close the socket"
        conn.close()
        return errors

    errors = asyncio.run(send_all())
    assert all(e["error"] and len(e["error"]) < 300 for e in errors), errors
    assert viz.alive()
    wait_for(lambda: "refused a browser message" in viz.log(), 5, "the refusals logged")
    assert "Traceback" not in viz.log(), viz.log()[-3000:]
    # A fresh page still gets served.
    import urllib.request
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as page:
        assert page.status == 200
