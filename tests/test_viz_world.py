"""What a world/info reply can make the viewer do (`zensim viz --world`, services/viz/world.py): bounded.

The viewer trusts world/info for nothing but a list of robots to fetch: at most 64 are shown, every id
must be a robot id (the schema's pattern lets a trailing newline through: the viewer checks again),
a robot named twice refuses the reply, and everything fetched for one world is capped. A running viz
answered with a hostile reply says why on its page, asks again at a bounded rate and keeps serving.
"""

from __future__ import annotations

import json
import threading
import time
import warnings
from collections.abc import Callable

import msgspec
import pytest
import zenoh

from support import Service, close_quietly, free_port, wait_for
from zensim.schemas import Codec, Keys, WorldInfo

with warnings.catch_warnings():  # meshcat imports pyzmq's deprecated ioloop; the tests turn warnings into errors
    warnings.simplefilter("ignore", DeprecationWarning)
    from zensim.viz import world


def world_info(ids: list[str]) -> WorldInfo:
    """A WorldInfo as the viewer decodes it off the wire (so the schema's own checks have run)."""
    robots = [{"robot": r, "model": "g1_29dof", "mode": "floating", "xy": [float(i), 0.0]} for i, r in enumerate(ids)]
    return Codec(WorldInfo).decode(msgspec.json.encode({"world": "lab", "robots": robots}))


def test_at_most_64_robots_are_shown_and_the_rest_counted() -> None:
    shown, left_out = world.checked_robots(world_info([f"r{i}" for i in range(100)]))
    assert [r.robot for r in shown] == [f"r{i}" for i in range(world.MAX_ROBOTS)] and left_out == 36
    assert world.checked_robots(world_info(["a", "b"]))[1] == 0


@pytest.mark.parametrize("ids, why", [
    (["a", "b", "a"], "names robot 'a' twice"),
    (["a", "b\n"], "robot id"),  # passes the schema's `^...$`, not a key chunk
    ([], "no robot"),
])
def test_a_bad_or_repeated_id_refuses_the_whole_reply(ids: list[str], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        world.checked_robots(world_info(ids))


def test_everything_fetched_for_one_world_is_capped() -> None:
    asked: list[int] = []

    def get(key: str, cap_bytes: int) -> bytes:
        asked.append(cap_bytes)
        return b"x" * 600

    get_within = world.budgeted(get, 1000)
    assert get_within("k", 10_000) == b"x" * 600 and asked == [1000]
    get_within("k", 10_000)
    assert asked[-1] == 400, "a reply may not be larger than what is left of the budget"
    with pytest.raises(ValueError, match="passed"):
        get_within("k", 10_000)
    assert len(asked) == 2, "nothing is asked once the budget is spent"


def test_a_running_viz_refuses_a_hostile_world_info_and_keeps_serving(
    start_service: Callable[..., Service], zsession: zenoh.Session, robot_id: str
) -> None:
    """A world/info from a hostile peer that names a robot twice: the viz fetches nothing for it, says why on
    the page, asks again every 2 s (not faster) and keeps serving."""
    import asyncio

    import tornado.websocket

    keys = Keys(robot_id + "-w")
    asked: list[float] = []
    lock = threading.Lock()

    def answer(query: zenoh.Query) -> None:
        with lock:
            asked.append(time.monotonic())
        robots = [{"robot": "x", "model": "m", "mode": "fixed", "xy": [0, 0]}] * 2
        query.reply(keys.world_info, json.dumps({"world": keys.robot, "robots": robots}),
                    encoding=zenoh.Encoding("application/json"))

    described: list[str] = []
    queryables = [zsession.declare_queryable(keys.world_info, answer),
                  zsession.declare_queryable(Keys("x").everything, lambda q: described.append(str(q.key_expr)))]
    try:
        port = free_port()
        viz = start_service("viz", "--port", str(port), "--world", keys.robot)
        wait_for(lambda: "names robot 'x' twice" in viz.log() or not viz.alive(), 30, "the refusal logged")
        time.sleep(5)
        with lock:
            gaps = [b - a for a, b in zip(asked, asked[1:])]
        assert 2 <= len(asked) <= 5 and min(gaps) > 1.5, asked
        assert not described and viz.alive(), (described, viz.log()[-2000:])

        async def status() -> dict:
            conn = await tornado.websocket.websocket_connect(f"ws://127.0.0.1:{port}/ws")
            try:
                while True:
                    message = await asyncio.wait_for(conn.read_message(), 10)
                    if isinstance(message, str) and json.loads(message).get("type") == "status":
                        return json.loads(message)
            finally:
                await close_quietly(conn)

        page = asyncio.run(status())
        assert "names robot 'x' twice" in page["description"] and page["robot"] is None, page
    finally:
        for queryable in queryables:
            queryable.undeclare()


def test_a_ghost_never_stands_on_a_neighbour() -> None:
    """The default offset (0.9 m to the left) would put a's ghost 0.1 m from b, a metre to its left: it goes
    to the other side; a crowd with no clear side gets its ghosts over the robots themselves."""
    offsets = world.ghost_offsets({"a": (0.0, 0.0), "b": (0.0, 1.0)}, (0.0, 0.9, 0.0))
    assert offsets == {"a": (0.0, -0.9, 0.0), "b": (0.0, 0.9, 0.0)}  # b: the left is clear
    crowd = {f"r{i}{j}": (0.5 * i, 0.5 * j) for i in range(3) for j in range(3)}
    placed = world.ghost_offsets(crowd, (0.0, 0.9, 0.0))
    assert placed["r11"] == (0.0, 0.0, 0.0)  # the middle one: every side has a neighbour
    alone = world.ghost_offsets({"solo": (3.0, 4.0)}, (0.0, 0.9, 0.0))
    assert alone == {"solo": (0.0, 0.9, 0.0)}
