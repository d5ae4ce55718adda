"""`zensim up`: the four services as local processes, stopped together by Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path


from support import free_port, plain_client, wait_for


def test_up_runs_everything_and_ctrl_c_stops_it(tmp_path: Path, robot_id: str) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    viz_port = free_port()
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, ZENSIM_PORT=str(viz_port), PYTHONUNBUFFERED="1",
               ZENSIM_MODE="fixed")
    log = (tmp_path / "up.log").open("wb")
    up = subprocess.Popen([sys.executable, "-m", "zensim", "up", "--router-endpoint", endpoint],
                          env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        with plain_client(endpoint, wait_for_router=True) as session:
            def alive() -> set[str]:
                replies = session.liveliness().get(f"zensim/{robot_id}/alive/*", timeout=1.0)
                return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

            wait_for(lambda: alive() >= {"router", "sim", "bridge", "viz"}, 60, "all four services", 0.2)
            with urllib.request.urlopen(f"http://127.0.0.1:{viz_port}/", timeout=5) as page:
                assert page.status == 200
            # The environment reached the services: the sim runs in the fixed mode.
            info = json.loads(next(iter(session.get(f"zensim/{robot_id}/info/robot?format=json"))).ok.payload.to_bytes())
            assert info["mode"] == "fixed"
        start = time.monotonic()
        up.send_signal(signal.SIGINT)  # what Ctrl-C in a terminal sends
        assert up.wait(15) == 0, (tmp_path / "up.log").read_text()
        assert time.monotonic() - start < 10
        text = (tmp_path / "up.log").read_text()
        for name in ("router", "sim", "bridge", "viz"):
            assert f"{name} exited with 0" in text, text
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        log.close()


def child_environ(up_pid: int, service: str) -> dict[str, str]:
    """The environment `zensim up` gave one of its services (read from /proc)."""
    for child in Path(f"/proc/{up_pid}/task/{up_pid}/children").read_text().split():
        cmdline = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        if cmdline[-2:-1] == [service.encode()] or service.encode() in cmdline[3:4]:
            entries = Path(f"/proc/{child}/environ").read_bytes().split(b"\0")
            return dict(e.decode().split("=", 1) for e in entries if b"=" in e)
    raise AssertionError(f"no {service} child of zensim up")


def test_each_service_gets_only_its_own_variables(tmp_path: Path, robot_id: str) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, PYTHONUNBUFFERED="1", ZENSIM_VIZ_PORT=str(free_port()),
               ZENSIM_BRIDGE_RATE_HZ="500", ZENSIM_VIZ_RATE_HZ="30", ZENSIM_SIM_MODE="fixed")
    log_path = tmp_path / "up.log"
    with log_path.open("wb") as log:
        up = subprocess.Popen([sys.executable, "-m", "zensim", "up", "--router-endpoint", endpoint],
                              env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            wait_for(lambda: "bridge up:" in log_path.read_text() and "viz up:" in log_path.read_text(), 60,
                     "the bridge and the viz up")
            text = log_path.read_text()
            assert "at 500 Hz" in text, "the bridge did not get ZENSIM_BRIDGE_RATE_HZ"
            assert "rate_hz=30.0" in text, "the viz did not get ZENSIM_VIZ_RATE_HZ"
            for service, own in (("sim", "ZENSIM_SIM_"), ("bridge", "ZENSIM_BRIDGE_"), ("viz", "ZENSIM_VIZ_")):
                got = {k for k in child_environ(up.pid, service) if k.startswith("ZENSIM_")}
                foreign = {k for k in got if k.split("_")[1] in ("SIM", "BRIDGE", "VIZ") and not k.startswith(own)}
                assert not foreign, f"{service} was given {sorted(foreign)}"
                assert "ZENSIM_ROBOT_ID" in got
            assert child_environ(up.pid, "bridge")["ZENSIM_BRIDGE_RATE_HZ"] == "500"
        finally:
            up.send_signal(signal.SIGINT)
            try:
                up.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(up.pid, signal.SIGKILL)


def test_a_variable_two_services_read_differently_stops_up_at_once() -> None:
    env = dict(os.environ, ZENSIM_RATE_HZ="500")
    done = subprocess.run([sys.executable, "-m", "zensim", "up"], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "ZENSIM_BRIDGE_RATE_HZ" in done.stderr and "ZENSIM_VIZ_RATE_HZ" in done.stderr
