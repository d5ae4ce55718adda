"""Unitree's wireless remote in zensim: a RemoteState put on cmd/remote (what the viewer's keys or gamepad send)
reaches LowState_.wireless_remote in Unitree's byte layout, on rt/lowstate and on the low-frequency copy
rt/lf/lowstate, and Unitree's own `example/wireless_controller/wireless_controller.py`, unchanged, prints it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from support import Latest, wait_for
from unitree_sdk import unused_domain_id
from zensim.schemas import Keys, UnitreeStatus
from zensim.schemas.messages import REMOTE_BUTTONS

SDK = os.environ.get("ZENSIM_UNITREE_SDK2_PYTHON", "")
pytestmark = pytest.mark.skipif(not SDK, reason="ZENSIM_UNITREE_SDK2_PYTHON is unset: Unitree's example is the client")
HERE = Path(__file__).parent


def printed_blocks(lines: list[str]) -> list[dict[str, float]]:
    """The example's `debug unitreeRemoteController:` blocks, each as {name: value}."""
    blocks: list[dict[str, float]] = []
    for line in lines:
        if line.startswith("debug unitreeRemoteController"):
            blocks.append({})
        elif blocks and ":" in line:
            name, _, value = line.partition(":")
            try:
                blocks[-1][name.strip()] = float(value)
            except ValueError:
                pass
    return [b for b in blocks if len(b) == 4 + len(REMOTE_BUTTONS)]  # whole blocks: Lx, Rx, Ry, Ly and every button


def test_unitrees_wireless_controller_example_prints_what_the_remote_sent(start_service, zsession, robot_id):
    from zensim.schemas import Codec, RemoteState

    keys = Keys(robot_id)
    domain = unused_domain_id()
    start_service("sim", "--mode", "fixed")
    adapter = start_service("unitree", "--domain-id", str(domain), "--interface", "lo")
    wait_for(lambda: "unitree adapter up" in adapter.log() or not adapter.alive(), 60, "the adapter to start")
    assert adapter.alive(), adapter.log()
    example = Path(SDK) / "example/wireless_controller/wireless_controller.py"
    proc = subprocess.Popen([sys.executable, "-u", str(HERE / "run_sdk_example.py"), str(domain), str(example), "lo"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    try:
        proc.stdin.write("\n")  # "Press Enter to continue..."
        proc.stdin.flush()
        # Nothing pressed yet: all zero.
        idle = wait_for(lambda: printed_blocks(list(lines)), 60, "the example to print the remote")[-1]
        assert all(v == 0 for v in idle.values()), idle
        pressed = RemoteState(buttons=("A", "Up", "L1", "Start"), lx=0.5, ly=-0.25, rx=0.125, ry=1.0)
        payload = Codec(RemoteState).encode(pressed, "json")

        def seen() -> dict | None:
            zsession.put(keys.remote, payload)
            blocks = printed_blocks(list(lines))
            return blocks[-1] if blocks and blocks[-1]["A"] == 1 else None

        block = wait_for(seen, 30, "the example to print the pressed buttons", 0.1)
        assert (block["Lx"], block["Ly"], block["Rx"], block["Ry"]) == (0.5, -0.25, 0.125, 1.0), block
        held = {name for name in REMOTE_BUTTONS if name != "L2" and block[name] == 1}
        assert held == {"A", "Up", "L1", "Start"}, block
        # A bad remote state (a button no remote has, a stick beyond 1, NaN) is refused whole and counted;
        # the last good one holds.
        status = Latest(zsession, keys.unitree_status, UnitreeStatus)
        for bad in ({"buttons": ["Z"]}, {"lx": 3.0}, {"ly": float("nan")}, {"buttons": ["A", "A"]}):
            zsession.put(keys.remote, json.dumps(bad))
        status.wait(lambda s: s.remote_rejected >= 4, 30, "the bad remote states counted")
        count = len(lines)
        wait_for(lambda: len(printed_blocks(lines[count:])) >= 2, 30, "more prints")
        assert printed_blocks(lines[count:])[-1] == block
        assert adapter.alive()
    finally:
        proc.kill()
        proc.wait(10)
        reader.join(10)
        proc.stdin.close()
        proc.stdout.close()
