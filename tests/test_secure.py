"""Secured links (`zensim secure init`, `--secure-dir`): real router and sim processes, Zenoh's own TLS,
passwords and access control; clients load the generated role configs as any Zenoh client would."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from support import Latest, Service, free_port, wait_for
from zensim.router import ACL_AUDIT_LOG
from zensim.schemas import JointState, SimStatus
from zensim.schemas.topics import ROLE_NAMES


@pytest.fixture(scope="module")
def secrets_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("sec") / "secrets"
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder), "--host", "sim-host.lan"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return folder


def strip_ansi(text: str) -> str:
    return re.sub(r"\x1b\[[0-9;]*m", "", text)


def role_conf(folder: Path, role: str, endpoint: str) -> zenoh.Config:
    """What a user does with DIR/<role>.json5: load it as is, add connect/endpoints."""
    conf = zenoh.Config.from_file(str(folder / f"{role}.json5"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return conf


def refused(conf: zenoh.Config) -> bool:
    try:
        session = zenoh.open(conf)
    except zenoh.ZError:
        return True
    session.close()
    return False


@pytest.fixture
def secured(secrets_dir: Path, tmp_path: Path, robot_id: str) -> Iterator[tuple[str, Service, Service]]:
    """A secured router and a fixed-mode sim on a free tls/ port: (endpoint, router, sim)."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(secrets_dir), ZENSIM_ROBOT_ID=robot_id, PYTHONUNBUFFERED="1")
    router_env = dict(env, RUST_LOG=ACL_AUDIT_LOG)  # the audit log docs/security.md describes
    router = Service("router", ["--zenoh-listen", endpoint], router_env, tmp_path)
    sim = None
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 20, "the secured router")
        assert router.alive(), router.log()
        sim = Service("sim", ["--zenoh-connect", endpoint, "--mode", "fixed"], env, tmp_path)
        yield endpoint, router, sim
    finally:
        if sim is not None:
            sim.stop()
        router.stop()


def test_init_writes_self_contained_role_configs(secrets_dir: Path) -> None:
    names = {p.name for p in secrets_dir.iterdir()}
    assert {"router.json5", "users.txt", "ca.pem"} | {f"{role}.json5" for role in ROLE_NAMES} <= names
    for role in ("operator", "viewer"):
        text = (secrets_dir / f"{role}.json5").read_text()
        assert str(secrets_dir) not in text  # no paths: the file works when copied to another machine
        zenoh.Config.from_file(str(secrets_dir / f"{role}.json5"))
    assert (secrets_dir / "users.txt").stat().st_mode & 0o077 == 0
    again = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(secrets_dir)],
                           capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "not empty" in again.stderr


@pytest.mark.parametrize("scope, says", [("nobody=a", "no role 'nobody'"), ("operator=BAD", "must match"),
                                         ("operator", "ROLE=ID")])
def test_init_refuses_a_bad_robot_scope_and_writes_nothing(tmp_path: Path, scope: str, says: str) -> None:
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(tmp_path / "s"), "--robots", scope],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and says in done.stderr, done.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="making a folder another user owns needs root")
def _owned_by_nobody(folder: Path) -> None:
    folder.mkdir()
    os.chown(folder, 65534, 65534)


@pytest.mark.parametrize("make, says", [
    (_owned_by_nobody, "belongs to another user"),
    (lambda d: (d.mkdir(), d.chmod(0o777)), "writable by others"),
    (lambda d: (d.mkdir(), d.chmod(0o770)), "writable by others"),
    (lambda d: ((d.parent / "real").mkdir(), d.symlink_to(d.parent / "real")), "symbolic link"),
], ids=["other-owner", "world-writable", "group-writable", "symlink"])
def test_init_refuses_an_empty_folder_someone_else_could_swap_files_in(tmp_path: Path, make, says: str) -> None:
    """An empty folder owned by another user (or writable by others) was accepted: its owner could later swap
    users.txt or router.json5 for their own."""
    folder = tmp_path / "secrets"
    make(folder)
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder)], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and says in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    assert not any(folder.iterdir()), "nothing is written"


@pytest.mark.parametrize("rust_log, refused", [
    ("debug", True), ("zenoh=debug", True), ("info,zenoh::api=trace", True),
    ("warn", False), ("warn,zenoh::net::routing::interceptor::access_control=trace", False),
])
def test_a_secured_service_refuses_a_rust_log_that_would_print_its_password(secrets_dir: Path, rust_log: str,
                                                                           refused: bool) -> None:
    """zenoh's debug log prints a session's whole config, the usrpwd password in clear: under --secure-dir a
    service refuses such a RUST_LOG in one line (the router's scoped audit directive stays allowed)."""
    password = next(line.split(":", 1)[1] for line in (secrets_dir / "users.txt").read_text().splitlines()
                    if line.startswith("bridge:"))
    # A router that accepts the TCP connection and never speaks: the bridge's session opens as far as a
    # real one would (its config logged on the way), then waits; it is stopped after a few seconds.
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        bridge = subprocess.Popen([sys.executable, "-m", "zensim", "bridge", "--secure-dir", str(secrets_dir),
                                   "--zenoh-connect", f"tls/127.0.0.1:{silent.getsockname()[1]}"],
                                  env=dict(os.environ, RUST_LOG=rust_log), stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True)
        try:
            output, _ = bridge.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            bridge.terminate()
            output, _ = bridge.communicate(timeout=20)
    assert password not in output, "the password in the log"
    assert ("would print this service's password" in output) == refused, output[-2000:]
    if refused:
        assert bridge.returncode == 2


def test_router_refuses_plain_tcp_wrong_password_and_foreign_certificates(
        secured: tuple[str, Service, Service], secrets_dir: Path, tmp_path: Path) -> None:
    endpoint, router, _ = secured
    plain = zenoh.Config()
    plain.insert_json5("mode", '"client"')
    plain.insert_json5("connect/endpoints", json.dumps(["tcp/" + endpoint.split("/", 1)[1]]))
    assert refused(plain)

    wrong_password = role_conf(secrets_dir, "operator", endpoint)
    wrong_password.insert_json5("transport/auth/usrpwd/password", '"not-the-password"')
    assert refused(wrong_password)

    # A certificate from another CA, presented to a router the client itself trusts.
    other = tmp_path / "other"
    subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(other)], check=True,
                   capture_output=True, timeout=60)
    foreign = role_conf(secrets_dir, "operator", endpoint)
    text = (other / "operator.json5").read_text()
    body = "\n".join(line for line in text.splitlines() if not line.startswith("//"))
    other_tls = json.loads(body)["transport"]["link"]["tls"]
    for field in ("connect_certificate_base64", "connect_private_key_base64"):
        foreign.insert_json5(f"transport/link/tls/{field}", json.dumps(other_tls[field]))
    assert refused(foreign)

    # The same credentials, unchanged, do connect: the refusals above are about what was changed.
    assert not refused(role_conf(secrets_dir, "operator", endpoint))
    assert router.alive()


def test_viewer_reads_but_cannot_drive_operator_can(secured: tuple[str, Service, Service], secrets_dir: Path,
                                                     robot_id: str) -> None:
    endpoint, router, sim = secured
    root = f"zensim/{robot_id}"
    with zenoh.open(role_conf(secrets_dir, "viewer", endpoint)) as viewer, \
            zenoh.open(role_conf(secrets_dir, "operator", endpoint)) as operator:
        joints = Latest(viewer, f"{root}/state/joints", JointState)
        status = Latest(operator, f"{root}/state/sim", SimStatus)
        joints.wait(timeout_s=60, what="state/joints at the viewer")
        info = json.loads(next(iter(viewer.get(f"{root}/info/robot?format=json", timeout=10))).ok.payload.to_bytes())
        assert info["mode"] == "fixed"
        status.wait(timeout_s=10)

        # The viewer's commands and control queries never reach the sim.
        name = info["joint_names"][0]
        motors = json.dumps({"names": [name], "q": [0.3], "kp": [20.0], "kd": [1.0]})
        for _ in range(20):
            viewer.put(f"{root}/cmd/motors", motors)
            viewer.put(f"{root}/cmd/motors", "{not json")  # would be counted as rejected if it arrived
            time.sleep(0.02)
        assert list(viewer.get(f"{root}/ctl/pause", payload="{}", timeout=2)) == []
        push = json.dumps({"direction": [1, 0, 0], "magnitude_n": 50, "duration_s": 0.1})
        assert list(viewer.get(f"{root}/ctl/push", payload=push, timeout=2)) == []
        assert list(viewer.get(f"{root}/ctl/band", payload='{"verb": "on"}', timeout=2)) == []
        limp = json.dumps({"verb": "set", "joints": [{"joint": name, "limp": True}]})
        assert list(viewer.get(f"{root}/ctl/faults", payload=limp, timeout=2)) == []
        before = status.value.seq
        seen = status.wait(lambda s: s.seq > before + 5, what="fresh status")
        assert seen.command_age_s is None and seen.rejected_commands == 0 and not seen.paused
        assert seen.pushes_applied == 0 and seen.rejected_requests == 0
        assert seen.faults is None and seen.faults_set == 0

        # Nobody but the sim publishes the sim's keys: a viewer's and another operator's forged status
        # never reach this operator (a session's own puts reach its own subscribers without the router).
        forged = json.dumps({"type": "sim_status", "sim_time_s": 0, "rtf": 1, "paused": True, "mode": "fixed",
                             "fallen": False, "run_id": "forged"})
        status.keep_history = True
        with zenoh.open(role_conf(secrets_dir, "operator", endpoint)) as forger:
            for _ in range(10):
                viewer.put(f"{root}/state/sim", forged)
                forger.put(f"{root}/state/sim", forged)
                time.sleep(0.05)
        status.wait(lambda s: s.seq > seen.seq + 5, what="more status")
        assert all(s.run_id != "forged" for s in status.history)

        # The operator drives the sim: its command arrives, its pause pauses.
        operator.put(f"{root}/cmd/motors", motors)
        status.wait(lambda s: s.command_age_s is not None, what="the operator's command to arrive")
        reply = json.loads(next(iter(operator.get(f"{root}/ctl/push", payload=push, timeout=10))).ok.payload.to_bytes())
        assert reply["ok"] and reply["push"]["body"] == "pelvis", reply
        reply = json.loads(next(iter(operator.get(f"{root}/ctl/faults", payload=limp, timeout=10))).ok.payload.to_bytes())
        assert reply["ok"] and reply["faults"]["joints"][0]["limp"] is True, reply
        reply = json.loads(next(iter(operator.get(f"{root}/ctl/pause", payload="{}", timeout=10))).ok.payload.to_bytes())
        assert reply["ok"], reply
        status.wait(lambda s: s.paused and s.pushes_applied == 1 and s.faults_set == 1,
                    what="the sim to pause, the push and the faults counted")
    assert sim.alive() and router.alive()
    # The router's audit log names who was refused what.
    for what in (f"is unauthorized to Put (ingress) on {root}/cmd/motors",
                 f"is unauthorized to Query (ingress) on {root}/ctl/pause"):
        wait_for(lambda: re.search(r"Username\(viewer\)[^\n]*" + re.escape(what), strip_ansi(router.log())),
                 5, f"the router's log line: viewer {what}")


def test_zensim_up_secured_runs_everything_and_operator_drives_through_the_bridge(
        secrets_dir: Path, tmp_path: Path, robot_id: str) -> None:
    """Each service's own role is enough for its job: the bridge moves a joint the operator asks for."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    viz_port = free_port()
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, ZENSIM_VIZ_PORT=str(viz_port), ZENSIM_SIM_MODE="fixed",
               PYTHONUNBUFFERED="1")
    up = Service("up", ["--secure-dir", str(secrets_dir), "--router-endpoint", endpoint], env, tmp_path)
    root = f"zensim/{robot_id}"
    try:
        conf = role_conf(secrets_dir, "operator", endpoint)
        conf.insert_json5("connect/timeout_ms", "60000")  # a minute, not for ever
        with zenoh.open(conf) as operator:
            def alive() -> set[str]:
                replies = operator.liveliness().get(f"{root}/alive/*", timeout=1.0)
                return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

            wait_for(lambda: alive() >= {"router", "sim", "bridge", "viz"} or not up.alive(), 90, "all four", 0.2)
            assert up.alive(), up.log()
            joints = Latest(operator, f"{root}/state/joints", JointState)
            joints.wait(timeout_s=30)
            info = json.loads(next(iter(operator.get(f"{root}/info/robot?format=json", timeout=10))).ok.payload.to_bytes())
            knee, target = info["joint_names"].index("left_knee_joint"), 0.3
            assert abs(joints.value.q[knee] - target) > 0.3
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and abs(joints.value.q[knee] - target) > 0.05:
                operator.put(f"{root}/cmd/joint/left_knee_joint", str(target))  # to the bridge, then cmd/motors
                time.sleep(0.2)
            assert joints.value.q[knee] == pytest.approx(target, abs=0.05), up.log()
            # The viz fetched the sim's description with its own role.
            wait_for(lambda: "description of" in up.log(), 30, "the viz's description fetch")
    finally:
        up.stop(15)


def test_zensim_up_unitree_secured_shows_the_adapter_to_an_operator(secrets_dir: Path, tmp_path: Path,
                                                                    robot_id: str) -> None:
    """The adapter runs with its own role: its alive/unitree token and state/unitree status reach an operator."""
    from unitree_sdk import unused_domain_id
    from zensim.schemas import UnitreeStatus

    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_ROBOT_ID=robot_id, ZENSIM_SIM_MODE="fixed", PYTHONUNBUFFERED="1",
               ZENSIM_UNITREE_DOMAIN_ID=str(unused_domain_id()), ZENSIM_UNITREE_STATUS_RATE_HZ="5")
    up = Service("up", ["--unitree", "--viz", "false", "--secure-dir", str(secrets_dir), "--router-endpoint", endpoint],
                 env, tmp_path)
    root = f"zensim/{robot_id}"
    try:
        conf = role_conf(secrets_dir, "operator", endpoint)
        conf.insert_json5("connect/timeout_ms", "60000")  # a minute, not for ever
        with zenoh.open(conf) as operator:
            status = Latest(operator, f"{root}/state/unitree", UnitreeStatus)

            def alive() -> set[str]:
                replies = operator.liveliness().get(f"{root}/alive/*", timeout=1.0)
                return {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None}

            wait_for(lambda: alive() >= {"router", "sim", "unitree"} or not up.alive(), 90, "alive/unitree", 0.2)
            assert up.alive(), up.log()
            status.wait(timeout_s=30, what="state/unitree at the operator")
    finally:
        up.stop(15)


def test_an_operator_scoped_to_robot_a_cannot_move_robot_b(tmp_path: Path) -> None:
    """`zensim secure init --robots operator=a`: on one secured router with sims `a` and `b`, the operator
    drives and reads `a`; its commands, control queries and subscriptions on `b` are refused by the router."""
    folder = tmp_path / "scoped"
    done = subprocess.run([sys.executable, "-m", "zensim", "secure", "init", str(folder), "--robots", "operator=a"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    endpoint = f"tls/127.0.0.1:{free_port()}"
    env = dict(os.environ, ZENSIM_SECURE_DIR=str(folder), PYTHONUNBUFFERED="1")
    router = Service("router", ["--zenoh-listen", endpoint], env, tmp_path)
    sims = []
    try:
        wait_for(lambda: "router up" in router.log() or not router.alive(), 20, "the secured router")
        for robot in ("a", "b"):
            sims.append(Service("sim", ["--zenoh-connect", endpoint, "--mode", "fixed", "--robot-id", robot],
                                env, tmp_path))
        with zenoh.open(role_conf(folder, "operator", endpoint)) as operator, \
                zenoh.open(role_conf(folder, "viewer", endpoint)) as viewer:
            mine = Latest(operator, "zensim/a/state/sim", SimStatus)
            theirs = Latest(operator, "zensim/b/state/sim", SimStatus)
            b_seen_by_viewer = Latest(viewer, "zensim/b/state/sim", SimStatus)  # an unscoped role sees b
            mine.wait(timeout_s=90, what="robot a's status at the operator")
            b_seen_by_viewer.wait(timeout_s=90, what="robot b's status at a viewer")
            motors = json.dumps({"names": ["left_elbow_joint"], "q": [0.3], "kp": [20.0], "kd": [1.0]})
            for _ in range(20):
                operator.put("zensim/b/cmd/motors", motors)
                time.sleep(0.02)
            assert list(operator.get("zensim/b/ctl/pause", payload="{}", timeout=2)) == []
            before = b_seen_by_viewer.value.seq
            seen = b_seen_by_viewer.wait(lambda s: s.seq > before + 5, what="b's fresh status")
            assert seen.command_age_s is None and not seen.paused, seen
            assert theirs.value is None  # b's states never reach an operator scoped to a
            # The same operator drives robot a.
            operator.put("zensim/a/cmd/motors", motors)
            mine.wait(lambda s: s.command_age_s is not None, what="the command on robot a")
            reply = json.loads(next(iter(operator.get("zensim/a/ctl/pause", payload="{}", timeout=10))).ok.payload.to_bytes())
            assert reply["ok"], reply
            mine.wait(lambda s: s.paused, what="robot a to pause")
        assert all(sim.alive() for sim in sims) and router.alive()
    finally:
        for sim in sims:
            sim.stop()
        router.stop()


def test_ros1_role_sends_joint_targets_but_never_motor_commands(secured: tuple[str, Service, Service],
                                                                secrets_dir: Path, robot_id: str) -> None:
    """The ROS 1 gateway's credentials: its targets go to the bridge's keys, a cmd/motors put is dropped."""
    endpoint, _router, _sim = secured
    root = f"zensim/{robot_id}"
    with zenoh.open(role_conf(secrets_dir, "ros1", endpoint)) as gateway, \
            zenoh.open(role_conf(secrets_dir, "operator", endpoint)) as operator:
        got: list[str] = []
        subscriber = operator.declare_subscriber(f"{root}/**", lambda s: got.append(str(s.key_expr)))
        joints = Latest(gateway, f"{root}/state/joints", JointState)
        joints.wait(timeout_s=60, what="state/joints at the gateway's role")
        assert next(iter(gateway.get(f"{root}/info/urdf", timeout=10))).ok is not None
        for _ in range(10):
            for key in ("cmd/joints", "cmd/joint/left_elbow_joint", "state/ros1", "cmd/motors", "state/sim"):
                gateway.put(f"{root}/{key}", "{}")
            time.sleep(0.05)
        wait_for(lambda: {f"{root}/cmd/joints", f"{root}/cmd/joint/left_elbow_joint", f"{root}/state/ros1"} <= set(got),
                 10, "the gateway role's puts")
        assert got.count(f"{root}/cmd/motors") == 0, "the ros1 role put a motor command past the bridge"
        subscriber.undeclare()
