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
from typing import Any

import yaml

from support import REPO, Service, free_port, plain_client, wait_for


def master_proxy(uri: str) -> Any:
    """An XML-RPC client of a ROS master; its replies are untyped nested lists, so it is typed Any."""
    return xmlrpc.client.ServerProxy(uri)

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
            with master_proxy(self.uri) as master:
                code, _, pid = master.getPid("/test")
            return pid if code == 1 else None
        except OSError:
            return None

    def param(self, name: str):
        """A parameter's value on this master (xmlrpc, no rospy node needed), or None when unset."""
        with master_proxy(self.uri) as master:
            code, _, value = master.getParam("/test", name)
        return value if code == 1 else None

    def publishers(self, topic: str) -> list[str]:
        """The nodes that publish `topic` according to this master."""
        with master_proxy(self.uri) as master:
            _, _, (publishers, _subscribers, _services) = master.getSystemState("/test")
        return next((nodes for name, nodes in publishers if name == topic), [])

    def subscribers(self, topic: str) -> list[str]:
        with master_proxy(self.uri) as master:
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
        """SIGINT (a terminal's Ctrl-C, what ROS programs expect), then SIGKILL after 5 s."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        self._log.close()


class Stack:
    """router, sim, bridge and `zensim ros1` processes for robot id g1, and a zenoh client."""

    def __init__(self, roscore: Roscore, log_dir, sim_args: tuple[str, ...] = (), bridge: bool = True) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        base = dict(os.environ, ZENSIM_ROBOT_ID="g1", ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1",
                    **roscore.env)
        self.services: list[Service] = []
        self.log_dir = log_dir
        self.client_env = dict(base, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=self.endpoint)
        router = self.start("router", env=dict(base, ZENSIM_ZENOH_LISTEN=self.endpoint))
        wait_for(lambda: "router up" in router.log() or not router.alive(), 15, "the router to start")
        self.sim = self.start("sim", *sim_args)
        if bridge:
            self.start("bridge")
        self.gateway = self.start("ros1", "--mesh-http-port", "0", "--status-rate-hz", "10")
        self.session = plain_client(self.endpoint)
        wait_for(lambda: "ros1 gateway up" in self.gateway.log() or not self.gateway.alive(), 60,
                 "the gateway to start")
        assert self.gateway.alive(), self.logs()

    def start(self, command: str, *args: str, env: dict[str, str] | None = None) -> Service:
        service = Service(command, list(args), env or self.client_env, self.log_dir)
        self.services.append(service)
        return service

    def logs(self) -> str:
        return "\n".join(f"----- {s.command} -----\n{s.log()[-3000:]}" for s in self.services)

    def close(self) -> None:
        self.session.close()
        for service in reversed(self.services):
            service.stop()


class Xvfb:
    """An X server of its own (`xvfb-run -a`, 1280x800x24) for GUI programs, screenshots and input events."""

    def __init__(self, tmp: Path) -> None:
        info = tmp / "display"
        self._holder = subprocess.Popen(
            [*XVFB, "sh", "-c", f'echo "$DISPLAY $XAUTHORITY" > {info}; exec sleep 3600'],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        wait_for(lambda: info.exists() and len(info.read_text().split()) == 2, 30, "Xvfb to start")
        display, xauthority = info.read_text().split()
        self.env = {"DISPLAY": display, "XAUTHORITY": xauthority}

    def run(self, *args: str, timeout_s: float = 30) -> str:
        result = subprocess.run(list(args), env={**os.environ, **self.env}, capture_output=True, text=True,
                                timeout=timeout_s)
        assert result.returncode == 0, f"{args}: {result.stderr[-1000:]}"
        return result.stdout

    def window(self, name: str) -> str | None:
        """The largest window whose title holds `name` (a toolkit's helper windows are 1x1), or None."""
        env = {**os.environ, **self.env}
        found = subprocess.run(["xdotool", "search", "--name", name], env=env, capture_output=True, text=True,
                               timeout=30).stdout.split()
        sizes = {}
        for window in found:
            shell = subprocess.run(["xdotool", "getwindowgeometry", "--shell", window], env=env, capture_output=True,
                                   text=True, timeout=30).stdout
            geometry = dict(line.split("=", 1) for line in shell.split() if "=" in line)
            sizes[window] = int(geometry.get("WIDTH", 0)) * int(geometry.get("HEIGHT", 0))
        best = max(sizes, key=sizes.get, default=None)
        return best if best is not None and sizes[best] > 100 else None

    def screenshot(self, path: Path):
        """The whole screen as an RGB numpy array (imagemagick's `import -window root`), also saved at `path`."""
        import numpy as np
        from PIL import Image

        self.run("import", "-window", "root", str(path))
        with Image.open(path) as image:
            return np.asarray(image.convert("RGB"))

    def stop(self) -> None:
        os.killpg(self._holder.pid, signal.SIGTERM)
        try:
            self._holder.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(self._holder.pid, signal.SIGKILL)
            self._holder.wait(5)
