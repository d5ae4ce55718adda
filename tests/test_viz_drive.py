"""Driving the G1 from the viewer page (issue 28 item 3): keys and a gamepad walk it through the viz
(`cmd/velocity`, `cmd/remote`), the camera follows it, a page opened with the viewer's token cannot drive,
and many pages' input storms are shed and counted. Real processes (sim, `zensim loco`, viz), real Zenoh,
Debian's chromium.

The sim runs under the lockstep clock as in tests/test_loco_process.py: the walking controller is the
clock, so the robot keeps its balance however loaded the machine (chromium draws in software here).
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable
from typing import Any

import pytest
import tornado.websocket
import zenoh

from browser import Browser
from support import Latest, Service, free_port, wait_for
from zensim.schemas import Keys, LocoStatus, Odometry, RemoteState, SimStatus, VelocityCommand, topics
from zensim.schemas.codec import Codec

BASE_LINK = "pelvis"
VIEW_FRACTION = 0.15
"""The robot's screen position may move less than this fraction of the view while it walks (followed)."""


class Heard:
    """Every sample of one key, decoded (the test's own plain subscriber)."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type) -> None:
        self.codec: Codec[Any] = Codec(message_type)
        self.messages: list = []
        self._sub = session.declare_subscriber(key, lambda s: self.messages.append(
            self.codec.decode(s.payload.to_bytes(), str(s.encoding))))


class Walkable:
    """A lockstep sim, `zensim loco` and a viz, with the test's subscribers."""

    def __init__(self, start: Callable[..., Service], session: zenoh.Session, robot_id: str, *viz_args: str) -> None:
        self.keys = Keys(robot_id)
        self.sim = start("sim", "--clock", "lockstep")
        self.odom = Latest(session, self.keys.odom, Odometry)
        self.status = Latest(session, self.keys.sim_status, SimStatus)
        self.status.keep_history = True
        self.loco_status = Latest(session, self.keys.loco_status, LocoStatus)
        self.velocity = Heard(session, self.keys.velocity, VelocityCommand)
        self.remote = Heard(session, self.keys.of(topics.REMOTE), RemoteState)
        self.odom.wait(timeout_s=60, what="the sim's first state")
        self.loco = start("loco")
        wait_for(lambda: "zensim loco up" in self.loco.log() or not self.loco.alive(), 60, "zensim loco to start")
        self.port = free_port()
        self.viz = start("viz", "--port", str(self.port), *viz_args)
        self.url = f"http://127.0.0.1:{self.port}/"

    def fell(self) -> bool:
        return any(s.fallen for s in self.status.history)


@pytest.fixture
def walkable(start_service, zsession, robot_id) -> Walkable:
    return Walkable(start_service, zsession, robot_id)


def open_page(browser: Browser, url: str) -> None:
    browser.goto(url)
    browser.wait("window.zensim && zensim.sceneReady", 90, "the robot drawn")
    browser.wait("zensim.status && zensim.status.loco", 30, "state/loco on the page")


def stand(browser: Browser, walkable: Walkable) -> None:
    browser.click("btn-stand")
    browser.wait("zensim.lastReply && zensim.lastReply.verb === 'loco walk' && zensim.lastReply.ok", 20, "Stand done")
    walkable.loco_status.wait(lambda s: s.walking, 60, "the controller walking (stood up)")
    browser.wait("document.getElementById('loco-state').textContent.startsWith('standing')", 20, "'standing' shown")


def test_w_walks_the_robot_the_camera_follows_it_and_space_stops_it(walkable: Walkable, browser: Browser) -> None:
    open_page(browser, walkable.url)
    assert "W" in browser.eval("document.getElementById('drive-keys').textContent")  # the keys are on the page
    stand(browser, walkable)
    start = walkable.odom.wait(what="odometry")
    screen_start = browser.eval(f"zensim.screenPosition('robot', '{BASE_LINK}')")
    browser.key("w", down=True)
    try:
        walkable.loco_status.wait(lambda s: s.commanded[0] > 0.4 and s.stepping, 20, "W in force")
        browser.wait("document.getElementById('vel-commanded').textContent.startsWith('0.50')", 10,
                     "the commanded velocity shown")
        screens, achieved = [], []
        for _ in range(20):  # 5 s of holding W, the view sampled every 0.25 s
            screens.append(browser.eval(f"zensim.screenPosition('robot', '{BASE_LINK}')"))
            achieved.append(browser.eval("zensim.loco.achieved[0]"))
            time.sleep(0.25)  # the sampling period of the view, not a wait for a condition
        walked = walkable.odom.value
    finally:
        browser.key(" ", down=True)  # space: stop (W is still held down: space lets go of every key)
        browser.key(" ", down=False)
        browser.key("w", down=False)
    distance = math.dist(start.pos[:2], walked.pos[:2])
    assert distance > 1.5, (start.pos, walked.pos)   # metres
    assert walked.pos[0] - start.pos[0] > 1.0 and max(achieved) > 0.3, achieved  # the page showed it walk
    drift = max(max(abs(x - screen_start[0]), abs(y - screen_start[1])) for x, y in screens) / 2.0  # NDC spans 2
    assert drift < VIEW_FRACTION, (screen_start, screens)
    stopped = walkable.loco_status.wait(lambda s: s.commanded == (0.0, 0.0, 0.0) and not s.stepping, 60,
                                        "space to stop the robot")
    assert stopped.walking and not walkable.fell()
    # The stop is the last put (it may wait for the viz's next tick after the rate's burst: under lockstep the
    # 1 s command timeout can lapse and stop the robot before it goes out).
    wait_for(lambda: walkable.velocity.messages[-1] == VelocityCommand(timeout_s=walkable.velocity.messages[-1].timeout_s),
             10, f"the stop put last: {walkable.velocity.messages[-3:]}")
    # The keys also filled Unitree's remote: W is the left stick forward.
    assert any(m.ly == 1.0 for m in walkable.remote.messages) and walkable.remote.messages[-1] == RemoteState()

    # One click turns the following off: the robot walks out of the middle of the view.
    browser.click("follow")
    assert browser.eval("zensim.follow") is False
    screen_start = browser.eval(f"zensim.screenPosition('robot', '{BASE_LINK}')")
    browser.key("w", down=True)
    try:
        unfollowed = wait_for(lambda: (lambda p: p if math.dist(p, screen_start) / 2.0 > VIEW_FRACTION else None)(
            browser.eval(f"zensim.screenPosition('robot', '{BASE_LINK}')")), 60, "the robot to leave the middle")
    finally:
        browser.key("w", down=False)
    print(f"followed: {distance:.2f} m walked, screen drift {drift:.3f} of the view; unfollowed: {unfollowed}")


def test_a_simulated_gamepad_stands_and_walks_the_robot(walkable: Walkable, browser: Browser) -> None:
    open_page(browser, walkable.url)
    buttons = "[{pressed: true}, {pressed: false}]"
    browser.eval(f"zensim.setGamepads([{{id: 'test pad', axes: [0, 0, 0, 0], buttons: {buttons}}}])")  # A: stand
    walkable.loco_status.wait(lambda s: s.walking, 60, "gamepad A to stand the robot up")
    start = walkable.odom.wait(what="odometry")
    browser.eval("zensim.setGamepads([{id: 'test pad', axes: [0, -1, 0, 0], buttons: []}])")  # left stick forward
    status = walkable.loco_status.wait(lambda s: s.stepping and s.commanded[0] > 0.9, 20, "the stick in force")
    assert status.commanded[0] == pytest.approx(status.velocity_limits[0])  # full tilt: the robot's limit
    walkable.odom.wait(lambda m: m.pos[0] - start.pos[0] > 1.0, 120, "the robot to walk a metre")
    browser.eval("zensim.setGamepads([{id: 'test pad', axes: [0, 0, 0, 0], buttons: []}])")
    walkable.loco_status.wait(lambda s: s.commanded == (0.0, 0.0, 0.0), 30, "the stick let go: stop")
    assert any(m.ly == 1.0 for m in walkable.remote.messages)
    assert any(m.buttons == ("A",) for m in walkable.remote.messages)
    assert "test pad" in browser.eval("document.getElementById('gamepad').textContent")
    assert not walkable.fell()


def test_a_viewer_token_page_watches_but_cannot_drive(start_service, zsession, robot_id, browser: Browser) -> None:
    keys = Keys(robot_id)
    heard = Heard(zsession, keys.velocity, VelocityCommand)
    port = free_port()
    viz = start_service("viz", "--port", str(port), "--token", "op-secret", "--viewer-token", "view-secret")
    wait_for(lambda: "pages that may watch, not drive" in viz.log() or not viz.alive(), 60, "the viz to serve")
    assert viz.alive(), viz.log()
    assert viz.log().count("view-secret") == 1  # once, as the viewer's URL; the settings line hides it
    browser.goto(f"http://127.0.0.1:{port}/?token=view-secret")
    browser.wait("zensim.role === 'viewer' && zensim.connected", 30, "the viewer's page")
    assert browser.eval("document.getElementById('drive-buttons').hidden && document.getElementById('controls').hidden")
    browser.key("w", down=True)
    browser.key("w", down=False)
    browser.eval("zensim.send({type: 'drive', vx: 0.5, vy: 0, wz: 0})")  # past the page's own checks
    browser.wait("zensim.lastError && zensim.lastError.includes('may watch, not drive')", 10, "the refusal")
    browser.eval("zensim.lastError = null; zensim.send({type: 'loco', verb: 'walk'})")
    browser.wait("zensim.lastError && zensim.lastError.includes('refused loco')", 10, "the walking verb refused")
    assert browser.eval("zensim.drive.sent") == 0 and heard.messages == []
    # The same viz drives for the operator's token.
    browser.goto(f"http://127.0.0.1:{port}/?token=op-secret")
    browser.wait("zensim.role === 'operator' && zensim.connected", 30, "the operator's page")
    browser.key("w", down=True)
    browser.key("w", down=False)
    wait_for(lambda: heard.messages and heard.messages[-1].vx == 0.0, 10, "the operator's W and its release")
    assert heard.messages[0].vx == 0.5, heard.messages  # W, (kept alive while held,) then the release


def test_drive_storms_from_many_pages_are_shed_and_counted_bad_velocities_refused(start_service, zsession,
                                                                               robot_id) -> None:
    keys = Keys(robot_id)
    heard = Heard(zsession, keys.velocity, VelocityCommand)
    port = free_port()
    viz = start_service("viz", "--port", str(port))
    wait_for(lambda: "viz up" in viz.log() or not viz.alive(), 60, "the viz to serve")
    pages, each = 8, 300

    async def storm() -> tuple[list[str], dict]:
        conns = [await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{port}/ws", max_message_size=64 << 20)
                 for _ in range(pages)]
        for i in range(each):  # a key-repeat storm: every page, as fast as it can
            for conn in conns:
                await conn.write_message(json.dumps({"type": "drive", "vx": round(0.001 * (i + 1), 3), "vy": 0, "wz": 0}))
        for bad in ({"vx": float("nan")}, {"vx": 1e9}, {"vx": 0, "lx": 5}, {"vx": "fast"}):
            await conns[0].write_message(json.dumps({"type": "drive", "vy": 0, "wz": 0, **bad}))
        errors: list[str] = []
        drive: dict = {}
        while len(errors) < 4 or drive.get("received", 0) < pages * each:  # every refusal told, every input counted
            message = json.loads(await asyncio.wait_for(conns[0].read_message(), 10))
            if message["type"] == "error":
                errors.append(message["error"])
            elif message["type"] == "status":
                drive = message["drive"]
        # One page, a burst and then its stop: the stop is the last put, however fast the burst came.
        for i in range(50):
            await conns[0].write_message(json.dumps({"type": "drive", "vx": 0.3, "vy": 0, "wz": 0}))
        await conns[0].write_message(json.dumps({"type": "drive", "vx": 0, "vy": 0, "wz": 0}))
        for conn in conns:
            conn.close()
        for conn in conns:  # until the server's close arrives: the sockets are closed, not left to the GC
            while await asyncio.wait_for(conn.read_message(), 10) is not None:
                pass
        return errors, drive

    errors, drive = asyncio.run(storm())
    assert any("finite" in e for e in errors) and any("absurd" in e for e in errors), errors
    assert drive["shed"] > pages * each / 2 and drive["sent"] + drive["shed"] <= drive["received"], drive
    wait_for(lambda: heard.messages and heard.messages[-1] == VelocityCommand(timeout_s=1.0), 10,
             f"the last input (the stop) put, not shed: {heard.messages[-3:]}, {len(heard.messages)}")
    assert len(heard.messages) < pages * each / 4  # paced: shed, not passed on
    wait_for(lambda: "shed so far" in viz.log(), 10, "the shedding logged")
    assert viz.alive()
