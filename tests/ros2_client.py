"""The test process's way to real ROS 2 code: tests/ros2_node.py run by .venv-ros2's Python (ROS 2 Kilted's
rclpy wheels), never imported here (its message packages would shadow Debian's ROS 1 ones).

`ZENSIM_ROS2_PYTHON` names another interpreter with the wheels; scripts/test makes .venv-ros2.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

from support import REPO

NODE = Path(__file__).with_name("ros2_node.py")


def ros2_python() -> str:
    python = Path(os.environ.get("ZENSIM_ROS2_PYTHON", REPO / ".venv-ros2" / "bin" / "python"))
    if not python.is_file():
        raise AssertionError(f"{python} not found: ROS 2's rclpy wheels go into .venv-ros2 (scripts/test makes it: "
                             "python3 -m venv .venv-ros2 && .venv-ros2/bin/pip install -r tests/ros2-requirements.txt)")
    return str(python)


def ros_env(domain: int) -> dict[str, str]:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
                PYTHONWARNINGS="ignore")


def run(*args: str, stdin: str = "", domain: int = 0, timeout_s: float = 60) -> list[str]:
    """Run ros2_node.py to the end; its output lines."""
    done = subprocess.run([ros2_python(), str(NODE), *args], input=stdin, env=ros_env(domain), capture_output=True,
                          text=True, timeout=timeout_s)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.splitlines()


def run_json(*args: str, domain: int = 0, timeout_s: float = 60) -> list[dict]:
    return [json.loads(line) for line in run(*args, domain=domain, timeout_s=timeout_s) if line.startswith("{")]


def serialize(*specs: dict) -> list[bytes]:
    """rclpy's serialize_message of each command spec (ros2_node.py `build`)."""
    lines = run("serialize", stdin="".join(json.dumps(s) + "\n" for s in specs))
    return [bytes.fromhex(line) for line in lines]


def deserialize(*items: tuple[str, bytes]) -> list[dict]:
    """rclpy's deserialize_message of each (type, CDR bytes), as JSON."""
    lines = run("deserialize", stdin="".join(json.dumps({"type": t, "hex": b.hex()}) + "\n" for t, b in items),
                timeout_s=120)
    return [json.loads(line) for line in lines]


def hashes() -> dict[str, str]:
    return json.loads(run("hashes")[-1])
