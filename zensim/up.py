"""`zensim up`: router, sim, bridge and viz as local processes, for a machine without Docker.

`zensim up --unitree` runs the Unitree DDS adapter in place of the bridge (docs/unitree.md).
`zensim up --loco` runs the walking controller (`zensim loco`) in place of the bridge, and `--unitree` runs
it too (the sport service forwards to it): the bridge and the walking controller both command every
motor, so one runs at a time. A robot without a walking controller: `zensim loco` says so and exits 0,
and the rest run on.
`zensim up --ros1` adds the ROS 1 gateway, and a ROS master when none answers at ROS_MASTER_URI (docs/ros.md),
both on loopback unless `--ros1-host` (or ROS_IP) names another address: ROS 1 has no authentication.
`zensim up --ros2` adds the ROS 2 face (`zensim ros2`: rmw_zenoh's keys on the router, and DDS; docs/ros.md).

The same four services as compose.yaml, wired the same way: a router listens
on one endpoint and the others join it as clients with multicast scouting off.
Ctrl-C (or SIGTERM) stops them all, newest first, and waits for each; if any
service dies on its own, the rest are stopped too and the exit code says so.
Each service gets only its own `ZENSIM_*` variables: the shared ones
(`ZENSIM_ROBOT_ID`, `ZENSIM_LOG_LEVEL`, `ZENSIM_ZENOH_*`) and those with its
prefix (`ZENSIM_SIM_MODE=fixed ZENSIM_BRIDGE_RATE_HZ=500 zensim up`).
"""

from __future__ import annotations

import importlib
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from typing import ClassVar, Final

import msgspec

from zensim.common.edges import check_edge, is_loopback
from zensim.common.logs import setup_logging
from zensim.common.session import StartupError
from zensim.common.settings import (AMBIGUOUS_LEGACY, ENV_PREFIX, LOCAL_ROUTER_ENDPOINT, SECURE_LOCAL_ROUTER_ENDPOINT, describe,
                                    env_names, settings_or_exit)
from zensim.common.shutdown import stop_on_signals
from zensim.schemas.keys import OPTIONAL_SERVICES, SERVICES

logger = logging.getLogger("zensim.up")

STOP_TIMEOUT_S = 10.0


class UpSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim up`."""

    env_prefix: ClassVar[str] = "UP"

    router_endpoint: str = LOCAL_ROUTER_ENDPOINT
    """Where the router listens and the other services connect."""
    viz: bool = True
    """Also run the web viewer."""
    unitree: bool = False
    """Run the Unitree DDS adapter (`zensim unitree`) in place of the bridge, with 500 Hz sim states: an SDK controller owns the motors."""
    loco: bool = False
    """Run the walking controller (`zensim loco`: cmd/velocity, ctl/loco) in place of the bridge; on with --unitree."""
    ros1: bool = False
    """Also run the ROS 1 gateway (`zensim ros1`), and a ROS master when none answers at ROS_MASTER_URI."""
    ros1_host: str = ""
    """Address the ROS 1 side (the master zensim up starts, the gateway's servers) binds and announces
    (`ROS_IP`); empty: ROS_IP from the environment, else 127.0.0.1. Beyond loopback anyone who reaches it
    drives the robot: ROS 1 has no authentication."""
    open_edges: bool = False
    """With --secure-dir, let the ROS 1 and Unitree DDS edges listen beyond loopback anyway (they are
    outside Zenoh's authentication: docs/security.md)."""
    ros2: bool = False
    """Also run the ROS 2 face (`zensim ros2`): ROS 2 nodes on rmw_zenoh (this router) or DDS see the robot."""
    log_level: str = "INFO"
    """Python log level of `zensim up` itself (the services follow ZENSIM_LOG_LEVEL)."""
    secure_dir: str | None = None
    """A folder made by `zensim secure init`: the router and services use TLS, passwords and roles."""


SETTINGS_OF: Final[dict[str, tuple[str, str]]] = {
    "router": ("zensim.router", "RouterSettings"),
    "sim": ("zensim.sim.settings", "SimSettings"),
    "bridge": ("zensim.bridge.settings", "BridgeSettings"),
    "viz": ("zensim.viz.settings", "VizSettings"),
    "unitree": ("zensim.unitree.settings", "UnitreeSettings"),
    "ros1": ("zensim.ros1.settings", "Ros1Settings"),
    "ros2": ("zensim.ros2.settings", "Ros2Settings"),
    "loco": ("zensim.loco.settings", "LocoSettings"),
}
"""Each service's settings struct (module, class), imported when needed: each module is light, no mujoco.
Keyed by keys.SERVICES (tests/test_facts.py checks that every service has one)."""


def settings_of(name: str) -> type[msgspec.Struct]:
    """The settings struct of a service `zensim up` runs. Raises KeyError for a name that is no service."""
    module, cls = SETTINGS_OF[name]
    settings: type[msgspec.Struct] = getattr(importlib.import_module(module), cls)
    return settings


def service_env(name: str, endpoint: str, environ: Mapping[str, str], secure_dir: str | None = None,
                unitree: bool = False, open_edges: bool = False) -> dict[str, str]:
    """The environment of one service: no `ZENSIM_*` variable but its own, and the way to the router.

    A service never sees another service's variables, so `ZENSIM_BRIDGE_RATE_HZ` cannot reach the viz.
    """
    own = env_names(settings_of(name))
    readable = set(own) | {legacy for legacy in own.values() if legacy}
    env = {key: value for key, value in environ.items() if not key.startswith(ENV_PREFIX) or key in readable}
    env.update(ZENSIM_ZENOH_MULTICAST_SCOUTING="false", PYTHONUNBUFFERED="1")
    if secure_dir:
        env["ZENSIM_SECURE_DIR"] = secure_dir
    if open_edges and name in ("ros1", "unitree"):
        env[f"ZENSIM_{name.upper()}_OPEN_EDGE"] = "true"
    if unitree and name == "sim" and "ZENSIM_STATE_RATE_HZ" not in env:
        env.setdefault("ZENSIM_SIM_STATE_RATE_HZ", "500")  # one LowState_ per 2 ms physics step
    if name == "router":
        env.update(ZENSIM_ZENOH_MODE="router", ZENSIM_ZENOH_LISTEN=endpoint)
        env.pop("ZENSIM_ZENOH_CONNECT", None)
    else:
        env.update(ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint)
        env.pop("ZENSIM_ZENOH_LISTEN", None)
    return env


BARE_FLAGS = ("--unitree", "--ros1", "--ros2", "--loco")


def _bare_unitree_flag(argv: Sequence[str] | None) -> list[str]:
    """`--unitree` (or `--ros1`) alone means `--unitree true` (every other flag takes a value)."""
    args = list(sys.argv[1:] if argv is None else argv)
    for i in reversed(range(len(args))):
        if args[i] in BARE_FLAGS and (i + 1 == len(args) or args[i + 1].startswith("--")):
            args.insert(i + 1, "true")
    return args


ROS_MASTER_DEFAULT = "http://localhost:11311"


def master_answers(uri: str, timeout_s: float = 1.0) -> bool:
    """Whether a ROS master answers at `uri` (its xmlrpc getPid)."""
    import socket
    import xmlrpc.client

    class Transport(xmlrpc.client.Transport):
        def make_connection(self, host):  # noqa: ANN001, ANN201 - the stdlib's signature
            connection = super().make_connection(host)
            connection.timeout = timeout_s
            return connection

    try:
        with xmlrpc.client.ServerProxy(uri, transport=Transport()) as master:
            return master.getPid("/zensim_up")[0] == 1  # type: ignore[index]  # xmlrpc answers a list
    except (OSError, socket.timeout, xmlrpc.client.Error):
        return False


MASTER_ENV = ("PATH", "HOME", "USER", "LOGNAME", "LANG", "LC_ALL", "LC_CTYPE", "TZ", "TMPDIR", "PYTHONPATH",
              "LD_LIBRARY_PATH", "CMAKE_PREFIX_PATH", "PKG_CONFIG_PATH")
"""Variables the ROS master gets besides ROS's own (`ROS_*`): what finds its programs and libraries.
Nothing else: roslaunch writes its environment into world-readable logs, and zensim's (a viewer token,
a secure folder) is none of its business."""


def master_env(environ: Mapping[str, str], host: str) -> dict[str, str]:
    """The ROS master's environment: ROS's variables, MASTER_ENV, and where it listens (ROS_IP)."""
    env = {key: value for key, value in environ.items() if key in MASTER_ENV or key.startswith("ROS_")}
    return ros_address_env(env, host)


def ros_address_env(env: dict[str, str], host: str) -> dict[str, str]:
    """`env` with ROS told to bind and announce `host` (ROS_IP; ROS_HOSTNAME would win over it)."""
    env.pop("ROS_HOSTNAME", None)
    env["ROS_IP"] = host
    return env


def ros1_address(settings: UpSettings, environ: Mapping[str, str]) -> str:
    """Where the ROS 1 side listens: --ros1-host, else ROS_IP, else loopback (ROS_HOSTNAME is only a name)."""
    return settings.ros1_host or environ.get("ROS_IP", "") or "127.0.0.1"


def start_roscore(uri: str, env: Mapping[str, str] | None = None) -> subprocess.Popen | None:
    """A ROS master (`rosmaster --core -p PORT`) for a local ROS_MASTER_URI no master answers at; None
    when one answers.

    roscore would also start rosout, whose XML-RPC server (roscpp's) listens on every interface
    whatever ROS_IP says: the master alone keeps the ROS side on loopback. `rosrun rosout rosout`
    adds the log aggregator for whoever wants it (docs/ros.md).

    Raises:
        OSError: ROS is not installed, or the URI names another host.
    """
    from urllib.parse import urlsplit

    if master_answers(uri):
        logger.info("a ROS master answers at %s: using it", uri)
        return None
    parts = urlsplit(uri)
    if parts.hostname not in ("localhost", "127.0.0.1", "::1"):
        raise OSError(f"no ROS master answers at {uri}, and zensim up starts one only on this machine")
    proc = subprocess.Popen(["rosmaster", "--core", "-p", str(parts.port or 11311)], start_new_session=True,
                            env=None if env is None else dict(env))
    logger.info("started the ROS master on port %d (pid %d)", parts.port or 11311, proc.pid)
    deadline = time.monotonic() + 30
    while not master_answers(uri):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise OSError(f"roscore did not answer at {uri}")
        time.sleep(0.2)
    return proc


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(UpSettings, _bare_unitree_flag(argv), "zensim up")
    ambiguous = sorted(name for name in AMBIGUOUS_LEGACY if os.environ.get(name))
    if ambiguous:
        new = "; ".join(f"{name}: use {' or '.join(AMBIGUOUS_LEGACY[name])}" for name in ambiguous)
        print(f"zensim up: no longer accepted, several services read it with different meanings: {new}",
              file=sys.stderr)
        return 2
    setup_logging(settings.log_level)
    logger.info("starting: %s", describe(settings))
    # Start the children before anything opens a zenoh session (fork after zenoh.open hangs).
    endpoint = settings.router_endpoint
    if settings.secure_dir and endpoint == UpSettings().router_endpoint:
        endpoint = SECURE_LOCAL_ROUTER_ENDPOINT
    if settings.secure_dir and not endpoint.startswith("tls/"):
        logger.error("with --secure-dir the router endpoint is tls/, not %s", endpoint)
        return 2
    names = [name for name in SERVICES if name not in OPTIONAL_SERVICES and (settings.viz or name != "viz")]
    roscore = None
    ros_host = ros1_address(settings, os.environ)
    if settings.ros1:
        names.append("ros1")
        try:
            check_edge("the ROS 1 side (master and gateway)", f"{ros_host} (--ros1-host / ROS_IP)",
                       is_loopback(ros_host), settings.secure_dir, settings.open_edges, logger, "--open-edges true")
        except StartupError as exc:
            logger.error("%s", exc)
            return 2
        try:
            roscore = start_roscore(os.environ.get("ROS_MASTER_URI", ROS_MASTER_DEFAULT),
                                    master_env(os.environ, ros_host))
        except OSError as exc:
            logger.error("--ros1: %s (install ROS 1: docs/ros.md)", exc)
            return 2
    if settings.unitree or settings.loco:
        # The bridge would command every motor at 100 Hz too: the SDK controller and the walking
        # controller (which the sport service drives) command the motors instead.
        names[names.index("bridge")] = "loco"
    if settings.ros2:
        names.append("ros2")
    if settings.unitree:
        names.insert(names.index("loco") + 1, "unitree")
    procs: dict[str, subprocess.Popen] = {}
    stop = stop_on_signals()
    for name in names:
        env = service_env(name, endpoint, os.environ, settings.secure_dir, settings.unitree, settings.open_edges)
        if name == "ros1":
            env = ros_address_env(env, ros_host)
        # Own process group: a terminal's Ctrl-C reaches only us, and we stop the children in order.
        procs[name] = subprocess.Popen([sys.executable, "-m", "zensim", name], env=env, start_new_session=True)
        logger.info("started %s (pid %d)", name, procs[name].pid)
    exit_code = 0
    while not stop.is_set():
        # `zensim loco` exits 0 at once for a robot without a walking controller (it says so): not a failure.
        dead = {name: p.returncode for name, p in procs.items()
                if p.poll() is not None and not (name == "loco" and p.returncode == 0)}
        if dead:
            logger.error("service(s) exited: %s; stopping the rest", dead)
            exit_code = 1
            break
        stop.wait(0.2)
    for name in reversed(names):
        proc = procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for name in reversed(names):
        proc = procs[name]
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            logger.warning("%s did not stop in time: killing it", name)
            proc.kill()
            proc.wait()
            exit_code = 1
        logger.info("%s exited with %s", name, proc.returncode)
    if roscore is not None:
        roscore.send_signal(signal.SIGINT)  # as a terminal's Ctrl-C
        try:
            roscore.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(roscore.pid, signal.SIGKILL)
            roscore.wait()
        logger.info("the ROS master exited with %s", roscore.returncode)
    return exit_code
