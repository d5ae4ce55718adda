"""The ROS 1 edge under attack and under stress, on real processes (Debian's ROS 1, a real router, sim and
gateway): a node shut down from outside exits instead of serving silently, SIGTERM ends the gateway while
the master is frozen, and secure mode keeps the ROS 1 and DDS edges on loopback unless opened explicitly.

The test process never becomes a ROS node here (test_ros1_process.py is the module that does): it speaks
to the master and the gateway over XML-RPC and runs Debian's ROS tools as subprocesses.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import xmlrpc.client
from typing import cast
from pathlib import Path

import pytest

from ros_graph import Roscore, Stack, Tool
from support import wait_for
from zensim.schemas import Keys

pytestmark = pytest.mark.skipif(not Path("/usr/bin/roscore").exists(), reason="needs Debian's ROS 1")

NODE = "/zensim_ros1_g1"
KEYS = Keys("g1")


def gateway_token_up(stack: Stack) -> bool:
    return any(r.ok is not None for r in stack.session.liveliness().get(KEYS.alive("ros1"), timeout=1.0))


def start_gateway(stack: Stack):
    gateway = stack.start("ros1", "--mesh-http-port", "0", "--status-rate-hz", "10")
    wait_for(lambda: "ros1 gateway up" in gateway.log() or not gateway.alive(), 60, "the gateway to start")
    assert gateway.alive(), gateway.log()
    wait_for(lambda: gateway_token_up(stack), 10, "alive/ros1")
    return gateway


def master_children(core: Roscore) -> dict[str, int]:
    """roscore's own processes by program name (rosmaster, rosout)."""
    pids = subprocess.run(["pgrep", "-P", str(core.proc.pid)], capture_output=True, text=True).stdout.split()
    found = {}
    for pid in pids:
        command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        found[Path(command[1 if command[0].endswith(b"python3") else 0].decode()).name] = int(pid)
    return found


@pytest.fixture(scope="module")
def ros_stack(tmp_path_factory):
    """A master, a router, a fixed-mode sim and a gateway; each test restarts the gateway it ends."""
    core = Roscore(tmp_path_factory.mktemp("ros"))
    stack = Stack(core, tmp_path_factory.mktemp("stack"), sim_args=("--mode", "fixed"), bridge=False)
    try:
        yield core, stack
    finally:
        stack.close()
        core.stop()


def ros_env(core: Roscore) -> dict[str, str]:
    return {**os.environ, **core.env}


def shut_by_rosnode_kill(core: Roscore, tmp_path: Path) -> Tool | None:
    subprocess.run(["rosnode", "kill", NODE], env=ros_env(core), capture_output=True, timeout=30, check=True)
    return None


def shut_by_an_xmlrpc_call(core: Roscore, tmp_path: Path) -> Tool | None:
    """What any host that reaches the node's XML-RPC port may send: no credential needed."""
    with xmlrpc.client.ServerProxy(core.uri) as master:
        code, _, uri = cast(list, master.lookupNode("/intruder", NODE))
    assert code == 1
    with xmlrpc.client.ServerProxy(str(uri)) as node:
        node.shutdown("/intruder", "bye")
    return None


def shut_by_taking_its_name(core: Roscore, tmp_path: Path) -> Tool:
    """Another node registers the same name: the master tells the gateway's node to shut down."""
    script = "import rospy, time; rospy.init_node('zensim_ros1_g1', disable_signals=True); time.sleep(120)"
    return Tool(["/usr/bin/python3", "-c", script], core.env, tmp_path / "impostor.log")


@pytest.mark.parametrize("shut_down", [shut_by_rosnode_kill, shut_by_an_xmlrpc_call, shut_by_taking_its_name],
                         ids=["rosnode-kill", "xmlrpc-shutdown", "name-taken"])
def test_a_gateway_whose_ros_node_is_shut_down_exits_non_zero_and_drops_its_token(ros_stack, shut_down,
                                                                                  tmp_path) -> None:
    """Once its node is shut down rospy never serves again: the gateway used to carry on, its alive/ros1 token
    and status claiming health while ROS output stopped and commands were ignored."""
    core, stack = ros_stack
    stack.gateway = start_gateway(stack)
    impostor = None
    try:
        impostor = shut_down(core, tmp_path)
        wait_for(lambda: not stack.gateway.alive(), 20, "the gateway to exit")
        assert stack.gateway.proc.returncode == 1, stack.gateway.log()[-3000:]
        assert "shut down from outside" in stack.gateway.log(), stack.gateway.log()[-3000:]
        wait_for(lambda: not gateway_token_up(stack), 10, "alive/ros1 to go")
    finally:
        if impostor is not None:
            impostor.stop()
        stack.gateway.stop()


def test_sigterm_ends_the_gateway_while_the_master_is_frozen(ros_stack) -> None:
    """A master that stopped answering (SIGSTOP) once held SIGTERM off until a SIGKILL 20 s later: rospy's
    shutdown unregisters every topic from the master with no timeout."""
    core, stack = ros_stack
    stack.gateway = start_gateway(stack)
    master = master_children(core)["rosmaster"]
    os.kill(master, signal.SIGSTOP)
    try:
        wait_for(lambda: "does not answer" in stack.gateway.log(), 20, "the gateway to notice the frozen master")
        started = time.monotonic()
        stack.gateway.signal(signal.SIGTERM)
        try:
            code = stack.gateway.proc.wait(10)
        except subprocess.TimeoutExpired:
            code = None
        took = time.monotonic() - started
    finally:
        os.kill(master, signal.SIGCONT)
        stack.gateway.stop()
    assert code == 0 and took < 5, (code, took, stack.gateway.log()[-3000:])


# ----------------------------------------------------------------------- secure mode: edges stay on loopback
@pytest.fixture(scope="module")
def secure_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("sec") / "secrets"
    subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder)], check=True, capture_output=True,
                   timeout=60)
    return folder


def zensim(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zensim", *args], env={**os.environ, **env}, capture_output=True,
                          text=True, timeout=60)


@pytest.mark.parametrize("command, env", [
    (["ros1"], {"ROS_IP": "192.0.2.10"}),
    (["ros1"], {"ROS_HOSTNAME": "robot.lan"}),
    (["unitree", "--interface", "eth0"], {}),
    (["unitree", "--interface", ""], {}),
    (["up", "--ros1", "--ros1-host", "192.0.2.10"], {}),
    (["up", "--ros1"], {"ROS_IP": "192.0.2.10"}),
], ids=["ros1-ros-ip", "ros1-ros-hostname", "unitree-eth0", "unitree-any", "up-ros1-host", "up-ros-ip"])
def test_secure_dir_refuses_an_edge_beyond_loopback_without_the_explicit_flag(secure_dir, command, env) -> None:
    """ROS 1 and DDS have no authentication: under --secure-dir, an edge beyond loopback is refused in one line
    (exit 2, before anything starts) that names the flag which opens it anyway."""
    result = zensim([*command, "--secure-dir", str(secure_dir)], env)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "no authentication" in result.stderr and "docs/security.md" in result.stderr, result.stderr
    assert ("--open-edges true" if command[0] == "up" else "--open-edge true") in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_without_secure_dir_an_edge_beyond_loopback_starts_with_one_warning(tmp_path) -> None:
    """Asked for (ROS_IP), the edge opens, with one clear warning; the gateway then waits for its sim."""
    log = (tmp_path / "ros1.log").open("wb")
    gateway = subprocess.Popen([sys.executable, "-m", "zensim", "ros1", "--zenoh-mode", "peer"],
                               env={**os.environ, "ROS_IP": "192.0.2.10", "PYTHONUNBUFFERED": "1"},
                               stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        text = lambda: (tmp_path / "ros1.log").read_text()  # noqa: E731
        wait_for(lambda: "asking the sim" in text() or gateway.poll() is not None, 30, "the gateway to start")
        assert gateway.poll() is None, text()
        warnings = [line for line in text().splitlines() if "no authentication" in line]
        assert len(warnings) == 1 and "WARNING" in warnings[0], text()
    finally:
        gateway.send_signal(signal.SIGTERM)
        gateway.wait(10)
        log.close()


def test_zensim_up_reports_a_gateway_whose_ros_node_was_killed_and_stops(tmp_path, robot_id) -> None:
    """`rosnode kill` of the gateway under `zensim up --ros1`: the gateway exits 1, and `zensim up` says which
    service died, stops the rest and exits 1 (it used to run on with a silent gateway)."""
    from support import free_port, plain_client

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ros = {"ROS_MASTER_URI": f"http://127.0.0.1:{free_port()}", "ROS_HOME": str(tmp_path / "ros")}
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(ros, ZENSIM_ROBOT_ID=robot_id, PYTHONUNBUFFERED="1", ZENSIM_SIM_MODE="fixed",
               ZENSIM_ROS1_MESH_HTTP_PORT="0")
    log_path = tmp_path / "up.log"
    with log_path.open("wb") as log:
        up = subprocess.Popen([sys.executable, "-m", "zensim", "up", "--router-endpoint", endpoint, "--viz", "false",
                               "--ros1"], env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        with plain_client(endpoint, wait_for_router=True) as session:
            wait_for(lambda: any(r.ok is not None for r in session.liveliness().get(
                Keys(robot_id).alive("ros1"), timeout=1.0)), 90, "the gateway", 0.2)
        node = f"/zensim_ros1_{robot_id}"
        subprocess.run(["rosnode", "kill", node], env={**os.environ, **ros, "ROS_IP": "127.0.0.1"},
                       capture_output=True, timeout=30, check=True)
        assert up.wait(30) == 1, log_path.read_text()
        text = log_path.read_text()
        assert "shut down from outside" in text and "'ros1': 1" in text, text
        assert "the ROS master exited with 0" in text, text
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
