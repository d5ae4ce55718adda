"""A flood on cmd/motors costs the sim bounded work: of each source only the newest command is decoded.

A real sim process; one plain client floods valid commands (no source info: one anonymous source)
as fast as it can, while a good client, whose samples say their source as zensim's publishers do,
moves the elbow. The flood's older samples are shed unread and counted as shed, not as errors, and
the good client's command is applied. How fast, under how large a flood, is benchmarks/overload.py.
"""

from __future__ import annotations

import itertools
import json
import threading
import time

import zenoh

from support import Latest, wait_for
from test_sim_process import joint_index, robot_info, wait_alive
from zensim.schemas import JointState, Keys, SimStatus

ELBOW = "left_elbow_joint"


def test_a_flood_from_one_source_is_shed_and_another_sources_command_still_applies(
        start_service, zsession: zenoh.Session, robot_id: str) -> None:
    keys = Keys(robot_id)
    joints = Latest(zsession, keys.joints, JointState)
    status = Latest(zsession, keys.sim_status, SimStatus)
    start_service("sim", "--mode", "fixed", "--watchdog-timeout-s", "30")
    wait_alive(zsession, keys)
    info = robot_info(zsession, keys)
    elbow = joint_index(info, ELBOW)
    default = info["default_q"][info["mode"]]
    others = [n for n in info["joint_names"] if n != ELBOW]
    flood = json.dumps({"names": others, "q": [default[info["joint_names"].index(n)] for n in others]}).encode()
    before = status.wait(what="a status")

    stop = threading.Event()
    sent = [0]

    def flooder() -> None:
        publisher = zsession.declare_publisher(keys.motors)
        while not stop.is_set():
            for _ in range(100):
                publisher.put(flood)
            sent[0] += 100
            time.sleep(0.001)

    thread = threading.Thread(target=flooder, daemon=True)
    thread.start()
    try:
        good = zsession.declare_publisher(keys.motors)
        sn = itertools.count(1)
        for target in (0.6, 0.2, 0.6):
            def sent_and_tracked(target: float = target) -> bool:
                good.put(json.dumps({"names": [ELBOW], "q": [target]}),
                         source_info=zenoh.SourceInfo(good.id, next(sn)))
                time.sleep(0.02)  # a 50 Hz controller
                return abs(joints.value.q[elbow] - target) < 0.05

            wait_for(sent_and_tracked, 20, f"the good client's elbow target {target} applied during the flood")
    finally:
        stop.set()
        thread.join(5)
    seq = status.value.seq
    after = status.wait(lambda m: m.seq > seq + 2, what="statuses after the flood")
    flooded = sent[0]
    shed = after.shed_commands - before.shed_commands
    assert flooded > 2000
    assert after.rejected_commands == before.rejected_commands, after.last_error  # shed is no error
    # Most of the flood was never decoded (the sim takes its queue every 2 ms: ~500 decodes a second).
    assert shed > flooded / 2, f"{shed} of {flooded} flood samples shed"
    assert after.sim_time_s > before.sim_time_s
