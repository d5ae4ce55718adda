"""Issue 9's findings, one test each: what a careless or hostile client sent, and what the services now do.

Real processes (`python -m zensim sim`, `bridge`), a real router on loopback, plain zenoh clients.
Each test names the finding it covers; each failed on the code before the fix.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time

import msgspec
import pytest
import zenoh

from support import Latest, Service, ctl, free_port, wait_for
from test_sim_process import command_until, put_json, sim_keys, wait_alive
from zensim.schemas import BridgeReport, Odometry, SimStatus
from zensim.schemas.codec import MAX_ERROR_CHARS

DEEP = b'{"q": [0.1], "x": ' + b"[" * 3_000 + b"]" * 3_000 + b"}"
"""Deep nesting in an unknown field: surfaced as RecursionError before the fix."""
BAD_UTF8 = b'{"names": ["left_elbow_joint\xff\xfe"], "q": [0.1]}'
"""Invalid UTF-8 in a string: surfaced as UnicodeDecodeError before the fix."""


def get_all(session: zenoh.Session, key: str, payload: bytes | str | None = None) -> list:
    return list(session.get(key, payload=payload, timeout=5.0))


def decode_reply(payload: bytes) -> dict:
    """A CtlReply in the request's format: JSON for JSON-looking requests, msgpack otherwise."""
    return json.loads(payload) if payload[:1] == b"{" else msgspec.msgpack.decode(payload)


def status_when(status: Latest, predicate, what: str, timeout_s: float = 10.0) -> SimStatus:
    return status.wait(predicate, timeout_s=timeout_s, what=what)


def no_traceback(*services: Service) -> None:
    for service in services:
        assert "Traceback" not in service.log(), f"{service.command} logged a traceback:\n{service.log()[-3000:]}"


def longest_log_line(service: Service) -> int:
    return max((len(line) for line in service.log().splitlines()), default=0)


class TestWildcardQueries:
    """Finding 1: `z_get zensim/g1/**` reset (20/20) and paused (9/20) the robot."""

    def test_a_wildcard_query_fires_no_control_and_every_queryable_answers(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        sim = start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        before = status_when(status, lambda m: m.steps > 50, "the sim stepping")
        for selector in (f"zensim/{robot_id}/**", f"zensim/{robot_id}/ctl/*", "zensim/**", "**"):
            replies = get_all(zsession, selector)
            by_key = {}
            for reply in replies:
                sample = reply.ok if reply.ok is not None else None
                if sample is not None:
                    by_key[str(sample.key_expr)] = sample
            for verb in ("reset", "pause", "resume", "step", "mode", "push", "band", "faults"):
                sample = by_key.get(keys.ctl(verb))
                assert sample is not None, f"{selector}: ctl/{verb} did not answer on its own key ({list(by_key)})"
                answer = json.loads(sample.payload.to_bytes())
                assert answer["ok"] is False and "exactly" in answer["error"], answer
            if selector != f"zensim/{robot_id}/ctl/*":
                assert keys.robot_info in by_key and keys.urdf in by_key, f"{selector}: info/* answered on own keys"
        after = status_when(status, lambda m: m.seq > before.seq + 3, "fresh statuses")
        assert after.resets == before.resets, "a wildcard query reset the robot"
        assert not after.paused, "a wildcard query paused the sim"
        assert after.steps > before.steps, "the sim stopped stepping"
        assert after.rejected_requests >= 5 * 3
        # The mesh queryable answered the wildcard with an error, not a traceback.
        no_traceback(sim)


class TestAbsurdValues:
    """Finding 2: finite but absurd values toppled the robot, froze sim time or launched it."""

    def test_absurd_torques_and_velocities_are_refused_and_the_robot_keeps_standing(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        odom = Latest(zsession, keys.odom, Odometry)
        start_service("sim")
        wait_alive(zsession, keys)
        odom.wait(lambda m: m.sim_time_s > 1.0, timeout_s=20, what="the robot settled")
        absurd = [
            {"names": ["left_knee_joint"], "q": [0.9], "tau": [1e11]},
            {"names": ["left_knee_joint"], "q": [0.9], "dq": [1e300], "kd": [500]},
            {"names": ["left_knee_joint"], "q": [1e300]},
            {"names": ["left_knee_joint"], "q": [-40.0]},
        ]
        for i, command in enumerate(absurd):
            seen = status.value.rejected_commands
            put_json(zsession, keys.motors, command)
            after = status_when(status, lambda m: m.rejected_commands == seen + 1, f"absurd command {i} counted")
            assert after.last_error and len(after.last_error) <= MAX_ERROR_CHARS
        t = odom.value.sim_time_s
        standing = odom.wait(lambda m: m.sim_time_s > t + 1.0, timeout_s=20, what="another sim second")
        assert standing.pos[2] > 0.6, f"the robot fell to {standing.pos[2]:.2f} m"
        assert status.value.physics_resets == 0

    def test_absurd_reset_heights_and_poses_are_refused_and_time_keeps_running(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        odom = Latest(zsession, keys.odom, Odometry)
        status = Latest(zsession, keys.sim_status, SimStatus)
        start_service("sim")
        wait_alive(zsession, keys)
        for height in (1e300, -10.0, 1e6, 0.0):
            answer = ctl(zsession, keys.ctl("reset"), {"base_height_m": height})
            assert answer["ok"] is False and "base_height_m" in answer["error"], (height, answer)
        answer = ctl(zsession, keys.ctl("reset"), {"names": ["left_knee_joint"], "q": [1e6]})
        assert answer["ok"] is False and "left_knee_joint" in answer["error"]
        t = odom.wait(what="a state").sim_time_s
        later = odom.wait(lambda m: m.sim_time_s > t + 0.5, timeout_s=20, what="sim time running")
        assert 0.5 < later.pos[2] < 1.0, f"base at {later.pos[2]} m"
        assert status.wait(lambda m: m.seq > 2).resets == 0
        # A sane height is still accepted.
        assert ctl(zsession, keys.ctl("reset"), {"base_height_m": 0.9})["ok"]

    def test_broken_physics_is_followed_by_a_real_reset_and_said(self, start_service, zsession, robot_id):
        # Allowed values that no integrator survives: the stiffest allowed gain, no damping, a 50 ms step.
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        odom = Latest(zsession, keys.odom, Odometry)
        sim = start_service("sim", "--timestep-s", "0.05", "--mode", "fixed")
        wait_alive(zsession, keys)
        joints = ["left_wrist_roll_joint", "left_wrist_pitch_joint", "left_wrist_yaw_joint", "left_elbow_joint"]
        stiff = {"names": joints, "q": [0.5] * 4, "kp": [5000.0] * 4, "kd": [0.0] * 4}
        command_until(zsession, keys.motors, stiff, lambda: status.value is not None and status.value.physics_resets > 0,
                      "the broken physics detected", timeout_s=20)
        said = status.wait(lambda m: m.physics_resets > 0 and m.last_reset_reason)
        assert "physics broke" in said.last_reset_reason
        assert said.resets >= said.physics_resets
        assert "resetting to the default pose" in sim.log()
        # Time keeps running after the reset (MuJoCo's own guard left it stuck at 0).
        t = odom.wait(what="a state").sim_time_s
        odom.wait(lambda m: m.sim_time_s > t + 0.5 or m.sim_time_s < t, timeout_s=20, what="time running")


class TestBoundedEcho:
    """Finding 3: a 10 MB joint name made a 10 MB SimStatus at 10 Hz, a 10 MB BridgeReport and log lines."""

    def test_long_names_are_not_echoed_and_oversize_payloads_are_refused_unread(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        reports = Latest(zsession, keys.bridge_report, BridgeReport)
        raw_sizes: list[int] = []
        sizes_sub = zsession.declare_subscriber(keys.sim_status, lambda s: raw_sizes.append(len(s.payload)))
        sim = start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        bridge = start_service("bridge")
        wait_alive(zsession, keys, "bridge")
        long_name = "j" * 15_000  # under the sim's cap: decoded, refused as an unknown joint
        over_cap = "j" * 40_000  # over the sim's cap (20 KiB for the G1): refused before decoding
        huge_name = "j" * 10_000_000  # over the router's size limit (64 KiB): dropped there
        for name in (long_name, over_cap):
            seen = status.wait(what="a status").rejected_commands
            put_json(zsession, keys.motors, {"names": [name], "q": [0.1]})
            refused = status_when(status, lambda m: m.rejected_commands == seen + 1, "the long name refused")
            assert len(refused.last_error) <= MAX_ERROR_CHARS
        assert "cap" in status.value.last_error
        seen = status.value.rejected_commands
        put_json(zsession, keys.motors, {"names": [huge_name], "q": [0.1]})
        count = len(raw_sizes)
        wait_for(lambda: len(raw_sizes) > count + 5, 5, "more statuses")
        assert status.value.rejected_commands == seen, "the router let a 10 MB payload through to the sim"
        assert max(raw_sizes[count:]) < 2048, f"SimStatus grew to {max(raw_sizes[count:])} bytes"
        for i, name in enumerate((long_name, over_cap), start=1):
            put_json(zsession, keys.joint_targets, {"names": [name], "q": [0.1]})
            report = reports.wait(lambda m, i=i: m.rejected_total >= i, what="a report")
            assert len(report.error) <= MAX_ERROR_CHARS and len(report.key) <= 200
        assert longest_log_line(sim) < 1000 and longest_log_line(bridge) < 1000
        sizes_sub.undeclare()


class TestDecodeFailures:
    """Finding 4: deep nesting and invalid UTF-8 escaped the handlers: uncounted tracebacks, ctl unanswered."""

    def test_every_decode_failure_is_counted_and_every_query_answered(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        reports = Latest(zsession, keys.bridge_report, BridgeReport)
        sim = start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        bridge = start_service("bridge")
        wait_alive(zsession, keys, "bridge")
        first = status.wait(what="a status")
        seen = first.rejected_commands + first.shed_commands
        for payload in (DEEP, BAD_UTF8):
            zsession.put(keys.motors, payload)
            zsession.put(keys.joint_targets, payload)
        # Rejected when decoded, or shed unread when the other (newer, same source) was already waiting
        # (the shed count may also hold a bridge command overtaken by the bridge's next on a slow machine).
        counted = status_when(status, lambda m: m.rejected_commands + m.shed_commands >= seen + 2, "both counted by the sim")
        assert 1 <= counted.rejected_commands - first.rejected_commands <= 2
        reports.wait(lambda m: m.rejected_total == 2, what="both counted by the bridge")
        for verb in ("reset", "pause", "resume", "step", "mode"):
            for payload in (DEEP, BAD_UTF8):
                replies = get_all(zsession, keys.ctl(verb), payload)
                assert len(replies) == 1, f"ctl/{verb}: {len(replies)} replies"
                answer = decode_reply(replies[0].ok.payload.to_bytes())
                assert answer["ok"] is False and answer["error"]
        assert not status.wait(lambda m: m.rejected_requests >= 10).paused
        no_traceback(sim, bridge)


class TestStrictControl:
    """Finding 5: ctl/pause and ctl/resume acted on any JSON object; some garbage got no reply."""

    def test_unknown_fields_are_refused_and_garbage_gets_exactly_one_reply(self, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        sim = start_service("sim", "--mode", "fixed")
        wait_alive(zsession, keys)
        for verb, payload in (("pause", {"foo": 1}), ("pause", {"paused": True}), ("resume", {"x": 0}),
                              ("step", {"n_steps": 5}), ("reset", {"base_height": 0.9}), ("mode", {"mode": "fixed", "z": 1})):
            answer = ctl(zsession, keys.ctl(verb), payload)
            assert answer["ok"] is False and "unknown field" in answer["error"].lower(), (verb, payload, answer)
        assert not status.wait(lambda m: m.seq > 2).paused
        import random

        rng = random.Random(9)
        for i in range(200):
            verb = rng.choice(("reset", "pause", "resume", "step", "mode"))
            garbage = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
            replies = get_all(zsession, keys.ctl(verb), garbage)
            assert len(replies) == 1 and replies[0].ok is not None, f"garbage #{i} on ctl/{verb}: {replies}"
            answer = decode_reply(replies[0].ok.payload.to_bytes())
            if answer["ok"]:  # only an empty-looking payload may mean "all defaults"
                assert not garbage.strip(b" \t\r\n"), (garbage, answer)
        assert ctl(zsession, keys.ctl("resume"))["ok"]
        no_traceback(sim)


def run_command(args: list[str], env: dict[str, str] | None = None, timeout_s: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "zensim", *args], capture_output=True, text=True, timeout=timeout_s,
                          env={**os.environ, "ZENSIM_ZENOH_MULTICAST_SCOUTING": "false", **(env or {})})


def one_line_exit_2(result: subprocess.CompletedProcess, *words: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("zensim ")]
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])


class TestSettingsAndShutdown:
    """Finding 7: NaN settings accepted, tracebacks at startup, silent waits, slow SIGTERM."""

    @pytest.mark.parametrize("args, named", [
        (["sim", "--watchdog-timeout-s", "nan"], "--watchdog-timeout-s"),
        (["sim", "--rtf", "nan"], "--rtf"),
        (["sim", "--state-rate-hz", "inf"], "--state-rate-hz"),
        (["sim", "--rtf", "-1"], "--rtf"),
        (["bridge", "--slew-rad-s", "nan"], "--slew-rad-s"),
        (["viz", "--query-timeout-s", "inf"], "--query-timeout-s"),
        (["sim", "--zenoh-connect", "tcp/127.0.0.1:99999"], "--zenoh-connect"),
        (["bridge", "--zenoh-connect", "foo/bar"], "--zenoh-connect"),
        (["router", "--zenoh-listen", "tcp/nowhere"], "--zenoh-listen"),
    ])
    def test_bad_settings_are_refused_with_their_name(self, args, named):
        one_line_exit_2(run_command(args), named)

    def test_startup_failures_are_one_line_naming_the_cause(self, tmp_path):
        missing = run_command(["sim", "--urdf", str(tmp_path / "nope.urdf")])
        one_line_exit_2(missing, "--urdf", "nope.urdf")
        broken = tmp_path / "broken.urdf"
        broken.write_text("<robot name='x'><link name='a'>")
        one_line_exit_2(run_command(["sim", "--urdf", str(broken)]), "--urdf", "XML")
        no_mesh = tmp_path / "no_mesh.urdf"
        no_mesh.write_text("""<robot name="m"><link name="base"><inertial><mass value="1"/>
          <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
          <link name="arm"><collision><geometry><mesh filename="meshes/missing.stl"/></geometry></collision>
          <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
          <joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/>
          <limit lower="-1" upper="1" effort="10" velocity="5"/></joint></robot>""")
        one_line_exit_2(run_command(["sim", "--urdf", str(no_mesh)]), "missing.stl")
        control = tmp_path / "control.toml"
        control.write_text("[model\nbroken =")
        one_line_exit_2(run_command(["sim", "--control", str(control)]), "--control", "control.toml")
        config = tmp_path / "zenoh.json5"
        config.write_text("{ mode: ")
        one_line_exit_2(run_command(["sim", "--zenoh-config-file", str(config)]), "--zenoh-config-file")
        with socket.socket() as busy:
            busy.bind(("127.0.0.1", 0))
            busy.listen()
            port = busy.getsockname()[1]
            one_line_exit_2(run_command(["router", "--zenoh-listen", f"tcp/127.0.0.1:{port}"]), "--zenoh-listen", "in use")
            one_line_exit_2(run_command(["viz", "--zenoh-mode", "peer", "--zenoh-listen", "tcp/127.0.0.1:0",
                                         "--port", str(port)]), "--port")

    def test_a_client_without_router_says_it_waits_and_stops_at_once(self, tmp_path):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        env = dict(os.environ, ZENSIM_ZENOH_MODE="client", ZENSIM_ZENOH_CONNECT=endpoint,
                   ZENSIM_ZENOH_MULTICAST_SCOUTING="false")
        bridge = Service("bridge", [], env, tmp_path)
        wait_for(lambda: f"waiting for the router at {endpoint}" in bridge.log(), 15, "the waiting line")
        started = time.monotonic()
        assert bridge.stop() == 0
        assert time.monotonic() - started < 2.0

    @pytest.mark.parametrize("command", ["sim", "bridge", "viz"])
    def test_sigterm_exits_0_within_2_s_with_the_router_frozen(self, command, router_endpoint, start_service, zsession, robot_id):
        keys = sim_keys(robot_id)
        status = Latest(zsession, keys.sim_status, SimStatus)
        sim = start_service("sim", "--mode", "fixed", "--state-rate-hz", "500")  # much traffic to back up
        wait_alive(zsession, keys)
        service = sim if command == "sim" else start_service(command, *(["--port", "0"] if command == "viz" else []))
        wait_alive(zsession, keys, command)
        status.wait(what="a status")
        router_pid = _router_pid(router_endpoint)
        os.kill(router_pid, signal.SIGSTOP)
        try:
            time.sleep(3.0)  # long enough for the links' send buffers to fill: then closing blocks
            started = time.monotonic()
            service.signal(signal.SIGTERM)
            code = service.proc.wait(10)
            took = time.monotonic() - started
        finally:
            os.kill(router_pid, signal.SIGCONT)
        assert code == 0, service.log()[-2000:]
        assert took < 2.0, f"{command} took {took:.1f} s to stop"
        assert "Traceback" not in service.log()


def _router_pid(endpoint: str) -> int:
    """The pid of the test's router process: the one listening on the endpoint's port."""
    port = endpoint.rsplit(":", 1)[1]
    out = subprocess.run(["ss", "-Hltnp", f"sport = :{port}"], capture_output=True, text=True).stdout
    pid = out.split("pid=")[1].split(",")[0]
    return int(pid)


FLOODER = r"""
import json, random, sys, time, zenoh
endpoint, root, seconds, rate = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
rng = random.Random(6)
keys = [f"{root}/cmd/motors", f"{root}/cmd/joints", f"{root}/cmd/joint/left_elbow_joint", f"{root}/state/sim",
        f"{root}/state/joints", f"{root}/cmd/joint/x", f"{root}/ctl/pause", f"{root}/info/robot", f"{root}/cmd/motors"]
payloads = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))) for _ in range(400)]
payloads += [b'{"q": [0.1], "x": ' + b"[" * 2000 + b"]" * 2000 + b"}", b'{"names": ["\xff"], "q": [1]}']
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    pubs = [session.declare_publisher(k) for k in keys]
    start, sent = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        if start + sent / rate > time.perf_counter():
            time.sleep(0.0005)
            continue
        pubs[sent % len(pubs)].put(payloads[sent % len(payloads)])
        sent += 1
    print("sent", sent, flush=True)
"""


class TestFloods:
    """Finding 6: 4 kHz of malformed samples over 9 keys cut states to 34 Hz, RTF to 0.0075, and flipped the watchdog."""

    def test_a_garbage_flood_neither_stalls_the_physics_nor_flips_the_watchdog(self, router_endpoint, start_service,
                                                                                zsession, robot_id, tmp_path):
        keys = sim_keys(robot_id)
        statuses: list[SimStatus] = []
        codec = msgspec.msgpack.Decoder(SimStatus)
        status_sub = zsession.declare_subscriber(keys.sim_status, lambda s: statuses.append(codec.decode(s.payload.to_bytes())))
        state_times: list[float] = []
        state_sub = zsession.declare_subscriber(keys.joints, lambda s: state_times.append(time.monotonic()))
        sim = start_service("sim", "--mode", "fixed")
        bridge = start_service("bridge", "--rate-hz", "100")  # the good client: commands at 100 Hz
        wait_alive(zsession, keys)
        wait_alive(zsession, keys, "bridge")
        wait_for(lambda: statuses and not statuses[-1].watchdog, 10, "the bridge's commands arriving")
        seconds = 5.0
        rejected_before = statuses[-1].rejected_commands
        flooder = subprocess.Popen([sys.executable, "-c", FLOODER, router_endpoint, keys.root, str(seconds), "4000"],
                                   stdout=subprocess.PIPE, text=True)
        wait_for(lambda: statuses[-1].rejected_commands > rejected_before, 10, "the flood reaching the sim")
        start, first_status = time.monotonic(), len(statuses)
        out, _ = flooder.communicate(timeout=seconds + 20)
        end = time.monotonic()
        during = statuses[first_status:]
        sent = int(out.split()[-1])
        assert sent > 0.8 * 4000 * seconds, f"the flooder sent only {sent}"
        assert during and not any(s.watchdog for s in during), "the watchdog flipped while the bridge kept commanding"
        wall = during[-1].sim_time_s - during[0].sim_time_s
        assert wall > 0.8 * (end - start - 0.5), f"sim time advanced {wall:.2f} s in {end - start:.2f} s of wall time"
        states = [t for t in state_times if start <= t <= end]
        assert len(states) > 0.7 * 100 * (end - start), f"{len(states)} states in {end - start:.1f} s (100 Hz nominal)"
        assert during[-1].rejected_commands > 0
        assert sim.alive() and bridge.alive()
        no_traceback(sim, bridge)
        status_sub.undeclare()
        state_sub.undeclare()


class TestBoundsWithoutLimits:
    """A URDF with no effort or velocity limits must not mean "any torque goes"."""

    def test_fallback_bounds_apply_when_the_description_gives_none(self, tmp_path) -> None:
        from zensim.robots import robot_files
        from zensim.schemas import MotorCommand
        from zensim.sim.physics import FALLBACK_EFFORT_LIMIT, CommandError, Limits
        from zensim.sim.world import World

        urdf = tmp_path / "nolimits.urdf"
        inertial = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
        urdf.write_text(f"""<robot name="nolimits"><link name="base">{inertial}</link><link name="arm">{inertial}</link>
          <joint name="j" type="continuous"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/></joint></robot>""")
        (sim,) = World.alone("nolimits", robot_files(urdf=urdf), "fixed", Limits(max_kp=5000, max_kd=500),
                             watchdog_timeout_s=0.5).robots
        sim.accept_command(MotorCommand(q=(0.1,), tau=(FALLBACK_EFFORT_LIMIT,)))
        with pytest.raises(CommandError, match="tau"):
            sim.accept_command(MotorCommand(q=(0.1,), tau=(1e11,)))
        with pytest.raises(CommandError, match="dq"):
            sim.accept_command(MotorCommand(q=(0.1,), dq=(1e300,), kd=(500.0,)))


def test_an_oversize_ctl_query_through_the_router_gets_an_error_reply(start_service, zsession, robot_id) -> None:
    """Issue 18: the router used to drop ctl queries over its size limit, and a dropped query gets no reply
    at all; the README says every ctl query gets one. The sim answers, refusing before it decodes."""
    keys = sim_keys(robot_id)
    start_service("sim", "--mode", "fixed")
    wait_alive(zsession, keys)
    for size in (30_000, 200_000):  # over the sim's cap; over the router's 64 KiB put limit too
        payload = json.dumps({"q": [0.0] * 10, "pad": "x" * size})
        replies = list(zsession.get(keys.ctl("reset"), payload=payload, timeout=10))
        assert len(replies) == 1 and replies[0].ok is not None, f"{size} bytes: no reply"
        reply = json.loads(replies[0].ok.payload.to_bytes())
        assert reply["ok"] is False and "cap" in reply["error"], reply
