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
