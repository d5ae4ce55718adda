"""ROS 1 for the tests, from Debian's packages as users install them: a private `roscore`, rospy in the
test process, and the GUI tools (rviz, joint_state_publisher_gui) under Xvfb.

Each test module gets its own master on a free port and its own ROS_HOME (logs), so parallel runs and
other engineers' masters never meet. rospy allows one node per process: only one test module
(test_ros1_process.py) makes the test process a ROS node; the GUI tests watch the sim over Zenoh.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import xmlrpc.client
from pathlib import Path

import yaml

from support import REPO, free_port, wait_for

DEBIAN_ROS_PYTHON = "/usr/lib/python3/dist-packages"
"""Where Debian's python3-rospy lives; the project's venv does not see it by itself (docs/ros.md)."""
XVFB = ["xvfb-run", "-a", "-s", "-screen 0 1280x800x24"]
JSP_GUI = REPO / "scripts" / "joint-state-publisher-gui"
RSP = "/usr/lib/robot_state_publisher/robot_state_publisher"
RVIZ_CONFIG = REPO / "deploy" / "ros1" / "zensim.rviz"


def import_rospy():
    """rospy, found the way `zensim ros1` finds it."""
    try:
        import rospy
    except ImportError:
        if DEBIAN_ROS_PYTHON not in sys.path:
            sys.path.append(DEBIAN_ROS_PYTHON)
        import rospy
    return rospy


class Roscore:
    """`roscore -p PORT` with its own ROS_HOME; `env` is what every process of the test's graph needs."""

    def __init__(self, home: Path, port: int | None = None) -> None:
        self.home = home
        self.port = port or free_port()
        self.uri = f"http://127.0.0.1:{self.port}"
        self.env = {"ROS_MASTER_URI": self.uri, "ROS_IP": "127.0.0.1", "ROS_HOME": str(home)}
        self.log_path = home / "roscore.out"
        home.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("wb")
        self.proc = subprocess.Popen(["roscore", "-p", str(self.port)], env={**os.environ, **self.env},
                                     stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        wait_for(lambda: self.pid() is not None or self.proc.poll() is not None, 30, "roscore to answer")
        assert self.proc.poll() is None, self.log_path.read_text()

    def pid(self) -> int | None:
        """The master's pid, or None while it does not answer."""
        try:
            with xmlrpc.client.ServerProxy(self.uri) as master:
                code, _, pid = master.getPid("/test")
            return pid if code == 1 else None
        except OSError:
            return None

    def param(self, name: str):
        """A parameter's value on this master (xmlrpc, no rospy node needed), or None when unset."""
        with xmlrpc.client.ServerProxy(self.uri) as master:
            code, _, value = master.getParam("/test", name)
        return value if code == 1 else None

    def publishers(self, topic: str) -> list[str]:
        """The nodes that publish `topic` according to this master."""
        with xmlrpc.client.ServerProxy(self.uri) as master:
            _, _, (publishers, _subscribers, _services) = master.getSystemState("/test")
        return next((nodes for name, nodes in publishers if name == topic), [])

    def subscribers(self, topic: str) -> list[str]:
        with xmlrpc.client.ServerProxy(self.uri) as master:
            _, _, (_publishers, subscribers, _services) = master.getSystemState("/test")
        return next((nodes for name, nodes in subscribers if name == topic), [])

    def echo_once(self, topic: str, timeout_s: float = 20) -> dict:
        """One message of `topic`, read by `rostopic echo -n 1` (Debian's rostopic, its own process)."""
        result = subprocess.run(["rostopic", "echo", "-n", "1", topic], env={**os.environ, **self.env},
                                capture_output=True, text=True, timeout=timeout_s)
        assert result.returncode == 0, result.stderr[-2000:]
        return yaml.safe_load(result.stdout.split("\n---")[0])

    def stop(self) -> None:
        """SIGINT, as a terminal's Ctrl-C: roscore stops rosmaster and rosout; then the whole group is killed."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(5)
        self._log.close()


class Tool:
    """A ROS program (rviz, robot_state_publisher, the GUI), started in its own process group."""

    def __init__(self, args: list[str], env: dict[str, str], log_path: Path) -> None:
        self.log_path = log_path
        self._log = log_path.open("wb")
        self.proc = subprocess.Popen(args, env={**os.environ, **env}, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        self._log.close()
