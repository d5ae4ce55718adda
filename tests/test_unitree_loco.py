"""The G1's high-level API through Unitree's own SDK (unitree_sdk2_python, unchanged) against `zensim up --unitree`:
LocoClient (the "sport" service) walks, turns and damps the floating G1 with Unitree's walking policy; the
SDK's arm_sdk and loco examples run as users run them; a lockstep walk re-simulates to 0 divergence.

Needs ZENSIM_UNITREE_SDK2_PYTHON (set by .ci/run; scripts/test then installs the SDK into the venv).
The walking tests share one running stack (module scope): it walks in sim time at real-time speed.
"""

from __future__ import annotations

import json
import math
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from support import Latest, ctl, free_port, plain_client, wait_for
from unitree_sdk import SdkClient, unused_domain_id
from zensim.schemas import Codec, JointState, Keys, MotorCommand, Odometry, SimStatus, UnitreeStatus

SDK = os.environ.get("ZENSIM_UNITREE_SDK2_PYTHON", "")
try:
    import unitree_sdk2py  # noqa: F401
    SDK_INSTALLED = True
except ImportError:
    SDK_INSTALLED = False
pytestmark = [
    pytest.mark.skipif(not SDK, reason="ZENSIM_UNITREE_SDK2_PYTHON is unset: Unitree's unitree_sdk2_python is the "
                                       "client of these tests (.ci/run points it at ../shared/unitree_sdk2_python)"),
    pytest.mark.skipif(bool(SDK) and not SDK_INSTALLED,
                       reason="unitree_sdk2py is not installed in this venv: run scripts/test with "
                              "ZENSIM_UNITREE_SDK2_PYTHON set (it pip-installs it --no-deps)"),
]
HERE = Path(__file__).parent
STACK_ENV = json.loads(os.environ.get("LOCO_STACK_ENV", "{}"))
ARMS = list(range(15, 29))


def yaw_of(quat_wxyz) -> float:
    w, x, y, z = quat_wxyz
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class Loco:
    """tests/sdk_loco.py: Unitree's LocoClient in its own process, one call per line."""

    def __init__(self, domain: int, log: Path) -> None:
        self._log = log.open("wb")
        self.proc = subprocess.Popen([sys.executable, str(HERE / "sdk_loco.py"), str(domain)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self._log, text=True)
        self.noise: list[str] = []
        # Its lines come through a thread, so that a client stuck in DDS fails the wait instead of hanging it.
        self._lines: queue.Queue[str] = queue.Queue()
        self._reader = threading.Thread(target=self._read_lines, daemon=True)
        self._reader.start()
        try:
            assert self._reply(60) == {"ready": True}
        except BaseException:
            self.proc.kill()
            self.close()
            raise

    def _read_lines(self) -> None:
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put("")

    def _reply(self, timeout_s: float = 30) -> dict:
        """The next JSON line; its SDK calls time out after 10 s, so 30 s without one means it hangs."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                line = self._lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"sdk_loco.py said nothing for {timeout_s} s") from None
            assert line, "sdk_loco.py exited"
            if line.startswith("{"):
                return json.loads(line)
            self.noise.append(line)  # the SDK prints its own diagnostics on stdout

    def call(self, *call):  # noqa: ANN201
        self.proc.stdin.write(json.dumps(call) + "\n")
        self.proc.stdin.flush()
        return self._reply()["result"]

    def close(self) -> None:
        self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
            raise
        finally:
            self._reader.join(5)  # at the exit's end of file: closing stdout under its read would raise there
            self.proc.stdout.close()
            self._log.close()
        if self.noise:
            print(f"\nthe SDK said: {''.join(self.noise)}")


class Stack:
    """`zensim up --unitree` (floating G1, 500 Hz states, no viewer) and a plain zenoh client watching it.

    `clock` "lockstep" makes the controller the clock: sim time then runs at the pace of the adapter's
    loop, whatever else loads the machine (a realtime sim on a machine with a load average of 15 on 2
    cores stalls for up to 90 ms, and a 50 Hz walking policy whose commands land that late stumbles).
    """

    OPEN: list[Stack] = []
    """The stacks running now (the module's two fixtures)."""

    def __init__(self, tmp: Path, clock: str = "realtime") -> None:
        self.robot_id = "t" + os.urandom(5).hex()
        self.keys = Keys(self.robot_id)
        self.domain = unused_domain_id()
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.tmp = tmp
        self.switcher: SdkClient | None = None
        env = dict(os.environ, ZENSIM_ROBOT_ID=self.robot_id, ZENSIM_UNITREE_DOMAIN_ID=str(self.domain),
                   PYTHONUNBUFFERED="1", ZENSIM_SIM_CLOCK=clock, **STACK_ENV)
        self.log_path = tmp / "up.log"
        self._log = self.log_path.open("wb")
        self.up = subprocess.Popen([sys.executable, "-m", "zensim", "up", "--unitree", "--viz", "false",
                                    "--router-endpoint", self.endpoint],
                                   env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        self.session = plain_client(self.endpoint, wait_for_router=True).__enter__()
        self.odom = Latest(self.session, self.keys.odom, Odometry)
        self.status = Latest(self.session, self.keys.sim_status, SimStatus)
        self.status.keep_history = True
        self.unitree = Latest(self.session, self.keys.unitree_status, UnitreeStatus)
        self.unitree.wait(timeout_s=90, what="the adapter's status")
        Stack.OPEN.append(self)
        if clock == "realtime":  # under lockstep time stands still (no state) until the controller starts
            self.odom.wait(timeout_s=30, what="the sim's odometry")

    def sim_time(self) -> float:
        return self.odom.wait(timeout_s=30, what="the sim's odometry").sim_time_s

    def run_for(self, seconds: float) -> Odometry:
        """Wait `seconds` of sim time (with room for a loaded machine)."""
        end = self.sim_time() + seconds
        return self.odom.wait(lambda m: m.sim_time_s >= end, 10 + 6 * seconds, f"{seconds} s of sim time")

    def run_until(self, sim_time_s: float) -> Odometry:
        """Wait for the first state at or after `sim_time_s`."""
        wall_s = 10 + 6 * max(0.0, sim_time_s - self.sim_time())
        return self.odom.wait(lambda m: m.sim_time_s >= sim_time_s, wall_s, f"sim time {sim_time_s:.2f} s")

    def fell_since(self, index: int) -> bool:
        return any(s.fallen for s in self.status.history[index:])

    def close(self) -> None:
        if self in Stack.OPEN:
            Stack.OPEN.remove(self)
        self.session.close()
        self.switcher = None
        self.up.send_signal(signal.SIGINT)
        try:
            self.up.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(self.up.pid, signal.SIGKILL)
        self._log.close()


def _stack(tmp_path_factory, request, clock: str):  # noqa: ANN202
    s = Stack(tmp_path_factory.mktemp(f"loco-{clock}"), clock)
    yield s
    s.close()
    if request.session.testsfailed:
        print(f"\n----- zensim up ({clock}) log -----\n{s.log_path.read_text()[-20000:]}")


@pytest.fixture(scope="module")
def stack(tmp_path_factory, request):
    """The realtime stack, for Unitree's examples (they pace themselves by the wall clock)."""
    yield from _stack(tmp_path_factory, request, "realtime")


@pytest.fixture(scope="module")
def lockstep_stack(tmp_path_factory, request):
    """The same stack under `clock: lockstep`, for the walk figures (10 s of sim time, in a few s)."""
    yield from _stack(tmp_path_factory, request, "lockstep")


G1_WEIGHT_N = 344.45
"""The bundled G1's total mass x g (tests/test_contacts_process.py reads it from the model)."""


def drives(stack: Stack) -> bool:
    """Whether the stack's walking controller still drives its robot (its adapter's newest status)."""
    return stack.unitree.value.loco_active


def fresh_start(stack: Stack) -> str:
    """The robot as after boot, whatever ran before: the controller released (the motion switcher's
    ReleaseMode, as a low-level program does it), the sim reset to its spawn squat."""
    # The other stack idles first: under lockstep a walking controller left balancing (or damping) drives its
    # sim flat out, two busy cores beside a realtime robot that must keep its balance by the wall clock.
    for other in Stack.OPEN:
        if other is not stack and other.switcher is not None:
            other.switcher.check_and_release_mode()
            wait_for(lambda: not drives(other), 10, "the other stack's controller released")
    if stack.switcher is None:
        stack.switcher = SdkClient(stack.domain)
    # What Unitree's low-level examples do first: CheckMode, ReleaseMode while a mode is active.
    calls = stack.switcher.check_and_release_mode()
    assert json.loads(stack.switcher.call(1001)[1])["name"] == ""
    wait_for(lambda: not stack.unitree.value.loco_active, 10, "the controller released")
    assert ctl(stack.session, stack.keys.ctl("reset"))["ok"]
    stack.odom.wait(lambda m: m.sim_time_s < 1.0, 10, "the state after the reset")
    return json.loads(calls[0][1])["name"]


def stand_up(stack: Stack, loco: Loco) -> str:
    """From the sim's spawn squat: squat-to-stand (FSM 706), which ends balancing on the policy.

    Returns:
        The mode the motion switcher named before the release ("sport" while the controller ran).
    """
    mode = fresh_start(stack)
    assert loco.call("SetFsmId", 706) == 0
    stack.run_for(3.0)
    assert stack.odom.value.pos[2] > 0.74, stack.odom.value  # the policy's stance (the squat: 0.725 m)
    return mode


def test_loco_client_squat_to_stand_walk_stop_turn_damp(lockstep_stack):
    stack = lockstep_stack
    loco = Loco(stack.domain, stack.tmp / "loco.log")
    try:
        fresh_start(stack)
        assert json.loads(stack.switcher.call(1001)[1]) == {"form": "0", "name": ""}
        assert loco.call("GetFsmId") == [0, 0]  # passive until asked (under lockstep: no time passes)
        first_status = len(stack.status.history)
        stand_up(stack, loco)
        assert loco.call("GetFsmId") == [0, 706]
        # Windows of sim time counted from before each call: under lockstep the sim runs on (several
        # times faster than the wall clock) while a request travels, so the robot walks at most 10 s.
        start = stack.odom.value
        stack.odom.keep_history = True
        loco.call("Move", 0.3, 0, 0, True)  # continous_move: duration 864000 s
        stack.run_for(0.5)
        # The newest SportModeState_ the SDK holds may predate the Move under lockstep (sim time outruns the
        # wall clock while a sample travels): ask again until one says walking.
        wait_for(lambda: loco.call("odommodestate")["mode"] == 3, 10, "SportModeState_ to say walking", 0.02)
        walked = stack.run_until(start.sim_time_s + 10.0)
        loco.call("StopMove")
        forward, lateral = walked.pos[0] - start.pos[0], walked.pos[1] - start.pos[1]
        walk_status = stack.status.history[first_status:]
        print(f"\nsim rtf min {min(x.rtf for x in walk_status):.2f} median {np.median([x.rtf for x in walk_status]):.2f}, "
              f"step jitter p99 max {max(x.step_jitter_p99_s for x in walk_status) * 1e3:.1f} ms; "
              f"heading {yaw_of(walked.quat_wxyz) - yaw_of(start.quat_wxyz):+.3f} rad; {forward:.2f} m, {lateral:+.2f} m")
        assert 2.0 <= forward <= 4.0, (start.pos, walked.pos)
        assert abs(lateral) < 0.5, (start.pos, walked.pos)
        # SportModeState_ read with the SDK's own type: the sim's ground truth at its stamp. (Under lockstep
        # the walking controller, not the adapter, is the clock: sim time runs several times faster than
        # the wall clock, so the newest SportModeState_ the SDK holds may be a second or two of sim time old.)
        state = loco.call("odommodestate")
        assert state is not None
        stamp = state["sec"] + state["nanosec"] * 1e-9
        # The ground truth at the stamp, between the two odometry samples around it (a loaded machine's
        # subscriber may miss a few: samples are dropped, never late, so the pair still brackets the stamp).
        before = max((m for m in stack.odom.history if m.sim_time_s <= stamp), key=lambda m: m.sim_time_s)
        after = min((m for m in stack.odom.history if m.sim_time_s >= stamp), key=lambda m: m.sim_time_s)
        assert after.sim_time_s - before.sim_time_s < 0.25, (stamp, before.sim_time_s, after.sim_time_s)
        ratio = 0.0 if after.sim_time_s == before.sim_time_s else (stamp - before.sim_time_s) / (after.sim_time_s - before.sim_time_s)
        truth_x = before.pos[0] + ratio * (after.pos[0] - before.pos[0])
        assert abs(state["position"][0] - truth_x) < 0.05, (state, before, after)
        stack.odom.keep_history = False
        # Stands still after StopMove (the policy balances in place).
        settled = stack.run_for(1.0)
        later = stack.run_for(3.0)
        drift = math.dist(settled.pos[:2], later.pos[:2])
        assert drift < 0.25, (settled.pos, later.pos)
        wait_for(lambda: loco.call("odommodestate")["mode"] == 1, 10, "SportModeState_ to say standing", 0.02)
        # Standing on both feet, as the SDK's own type reads foot_force: the sim's contact normal forces, N
        # (left, right; a quadruped's hind feet stay 0), together the robot's weight give or take its sway.
        left, right, *hind = loco.call("odommodestate")["foot_force"]
        assert hind == [0, 0] and left > 50 and right > 50, (left, right, hind)
        assert 0.75 * G1_WEIGHT_N < left + right < 1.25 * G1_WEIGHT_N, (left, right)
        # Turns in place: 0.3 rad/s for at most 5 s.
        loco.call("Move", 0, 0, 0.3, True)
        # Counted from the reply (the sport service forwards the turn before it answers): under lockstep the sim
        # runs on while a request travels, and once in CI that was over a second of the 5 s (0.70 rad turned).
        before_turn = stack.odom.value
        turned = stack.run_until(before_turn.sim_time_s + 5.0)
        loco.call("StopMove")
        turn = (yaw_of(turned.quat_wxyz) - yaw_of(before_turn.quat_wxyz) + math.pi) % (2 * math.pi) - math.pi
        assert 0.8 < turn < 1.8, turn
        assert math.dist(turned.pos[:2], before_turn.pos[:2]) < 0.5, (before_turn.pos, turned.pos)
        assert not stack.fell_since(first_status), "the robot fell while walking"
        print(f"\nover the wire: walked {forward:.2f} m forward, {lateral:+.2f} m lateral in 10 s; "
              f"{drift:.3f} m in 3 s after StopMove; turned {turn:+.2f} rad in 5 s")
        # Unsupported calls get the robot's error codes, not silence.
        assert loco.call("SetTaskId", 0) == 3203  # arm tasks (wave hand): not implemented
        assert loco.call("SetFsmId", 12345) == 3204  # not an FSM id: parameter error
        assert loco.call("SetFsmId", 706) == 0 and loco.call("GetFsmId") == [0, 706]  # the FSM toggles to squat
        stack.run_for(2.0)
        # Damp lets it fold. (First the motion switcher names the running controller, and releases it.)
        assert stand_up(stack, loco) == "sport"
        upright = stack.odom.value.pos[2]
        loco.call("Damp")
        folded = stack.run_for(3.0)
        assert folded.pos[2] < upright - 0.15, (upright, folded.pos)
        stack.unitree.wait(lambda u: u.loco_fsm_id == 1 and u.policy_steps > 500, 10, "the status to say damp")
    finally:
        loco.close()


class Recorder:
    """Joint states and the commands the controller sends, stamped with their arrival (wall) time."""

    def __init__(self, stack: Stack) -> None:
        self.joints: list[tuple[float, JointState]] = []
        self.motors: list[tuple[float, MotorCommand]] = []
        jc, mc = Codec(JointState), Codec(MotorCommand)
        self._subs = [
            stack.session.declare_subscriber(stack.keys.joints, lambda s: self.joints.append(
                (time.monotonic(), jc.decode(s.payload.to_bytes(), str(s.encoding))))),
            stack.session.declare_subscriber(stack.keys.motors, lambda s: self.motors.append(
                (time.monotonic(), mc.decode(s.payload.to_bytes(), str(s.encoding))))),
        ]

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def test_sdk_arm7_example_moves_the_arms_over_the_standing_robot(lockstep_stack):
    # Under lockstep: the example paces itself by the wall clock (50 Hz, 21 s) while the robot's time
    # runs at the controller's pace, so a loaded machine cannot make the balancing robot stumble; the
    # arms' tracking is measured in wall time, as the example sees it.
    stack = lockstep_stack
    loco = Loco(stack.domain, stack.tmp / "loco-arm.log")
    try:
        stand_up(stack, loco)
    finally:
        loco.close()
    first_status = len(stack.status.history)
    recorder = Recorder(stack)
    example = Path(SDK) / "example/g1/high_level/g1_arm7_sdk_dds_example.py"
    done = subprocess.run([sys.executable, str(HERE / "run_sdk_example.py"), str(stack.domain), str(example), "lo"],
                          input="\n", capture_output=True, text=True, timeout=90)
    time.sleep(1.0)
    recorder.close()
    assert "Done!" in done.stdout, done.stdout + done.stderr
    assert not stack.fell_since(first_status), "the robot fell under arm_sdk"
    assert stack.unitree.value.arm_sdk_received > 500 and stack.unitree.value.arm_sdk_rejected == 0
    # Arm joints follow the commanded targets (RMS after a 50 ms lag) while arm_sdk holds weight 1 and
    # lifts the arms and lowers them again (the example's stages 2 and 3: from 3 s to 18 s of its run;
    # its stage 2 starts when the commanded left elbow leaves 0).
    t0 = next(t for t, m in recorder.motors if m.q[18] > 0.02)
    motor_times = np.array([t for t, _ in recorder.motors])
    errors = []
    for t, state in recorder.joints:
        if not t0 + 0.5 < t < t0 + 14.5:
            continue
        i = np.searchsorted(motor_times, t - 0.05) - 1
        if i < 0:
            continue
        target = np.asarray(recorder.motors[i][1].q)[ARMS]
        errors.append(np.asarray(state.q)[ARMS] - target)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    print(f"\narm_sdk: arm RMS {rms:.4f} rad after a 50 ms lag over {len(errors)} states")
    assert rms < 0.05, rms
    lifted = max(abs(s.q[18]) for t, s in recorder.joints)  # left elbow to pi/2 at the top
    assert lifted > 1.2, lifted
    # The release (stage 4, weight 1 -> 0 over 3 s, from 18 s of its run) and the second after: the arms
    # go back to the controller without a jump.
    steps = [(np.max(np.abs(np.asarray(b.q)[ARMS] - np.asarray(a.q)[ARMS])), ta - t0)
             for (ta, a), (_, b) in zip(recorder.joints, recorder.joints[1:]) if b.seq == a.seq + 1]
    largest = max(steps)
    released = max(step for step, t in steps if t > 14.5)
    def speed(start: float, end: float) -> float:
        return max(np.max(np.abs(np.asarray(m.dq)[ARMS])) for t, m in recorder.joints if t0 + start < t < t0 + end)

    before, during, after = speed(13.0, 15.0), speed(15.0, 18.0), speed(18.0, 1e9)
    print(f"largest change of an arm joint between consecutive states: {largest[0]:.4f} rad at {largest[1]:.2f} s; "
          f"during and after the release: {released:.4f} rad; arm joint speeds at most {before:.3f} rad/s before "
          f"the release, {during:.3f} during, {after:.3f} after")
    # The arms move a little all along (the policy balances by stepping in place, more on a loaded machine):
    # a jump at the release (weight 1 -> 0 at once) shows as arm speeds of 1 rad/s and more.
    assert released < 0.02 and max(during, after) < 2 * before + 0.8, (released, before, during, after)


def test_sdk_loco_client_example_through_its_stdin(stack):
    # The robot as after boot: in the spawn squat, the controller passive. The example's first choice
    # damps for 0.5 s (wall clock: so the realtime stack) before standing up; from a robot balancing on
    # the policy, caught with one foot in the air, that drops it sideways, as it would drop a real one.
    fresh_start(stack)
    example = Path(SDK) / "example/g1/high_level/g1_loco_client_example.py"
    proc = subprocess.Popen([sys.executable, str(HERE / "run_sdk_example.py"), str(stack.domain), str(example), "lo"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.extend(proc.stdout), daemon=True)
    reader.start()

    def prompts() -> int:
        return "".join(output).count("Enter id or name")

    def choose(line: str, seconds: float) -> Odometry:
        """Give the example `line`, wait until it has made its calls (its next prompt: after its requests
        were answered and its 1 s pause), then `seconds` of sim time for the robot to act them out.

        Waiting on the prompt, not on sim time alone: on a loaded machine the example can take many
        seconds to start (imports, DDS) or to get to a line, while the sim's clock runs on (once it had not
        read "1" before its 4 s window ended, and the test saw no stand-up)."""
        asked = prompts()
        proc.stdin.write(line + "\n")
        proc.stdin.flush()
        wait_for(lambda: prompts() > asked or proc.poll() is not None, 120, f"the example to act on {line!r}")
        trace = []
        end = stack.sim_time() + seconds
        while stack.sim_time() < end:
            trace.append(stack.odom.value)
            stack.run_for(0.25)
        print(f"\n{line!r}: " + " ".join(f"({m.sim_time_s:.2f} {m.pos[0]:+.2f} {m.pos[1]:+.2f} {m.pos[2]:.2f})" for m in trace))
        return stack.odom.value

    def pace() -> str:
        """How the realtime sim kept time over the test (a balancing policy whose commands land late
        stumbles: say so when the robot falls, so a starved machine is told from a broken controller)."""
        window = stack.status.history[first_status:]
        if not window:
            return "no sim status"
        return (f"sim rtf min {min(x.rtf for x in window):.2f}, step jitter p99 max "
                f"{max(x.step_jitter_p99_s for x in window) * 1e3:.0f} ms, load average {os.getloadavg()[0]:.1f}")

    try:
        first_status = len(stack.status.history)
        choose("", 1.0)  # "Press Enter to continue..."
        stood = choose("1", 4.0)  # Damp, 0.5 s, Squat2StandUp
        assert stood.pos[2] > 0.7, (stood.pos, pace())
        stack.unitree.wait(lambda u: u.loco_fsm_id == 706, 10, "the status to say squat-to-stand")
        moved = choose("3", 2.5)  # Move(0.3, 0, 0) for 1 s
        assert moved.pos[0] - stood.pos[0] > 0.1, (stood.pos, moved.pos, pace())
        turned = choose("5", 2.5)  # Move(0, 0, 0.3) for 1 s
        assert abs(yaw_of(turned.quat_wxyz) - yaw_of(moved.quat_wxyz)) > 0.1, pace()
        assert not stack.fell_since(first_status), pace()
        damped = choose("0", 2.5)  # Damp
        assert damped.pos[2] < turned.pos[2] - 0.05, (turned.pos, damped.pos, pace())
        stack.unitree.wait(lambda u: u.loco_fsm_id == 1, 10, "the status to say damp")
        print(f"\nthe example's run: {pace()}")
    finally:
        proc.stdin.close()
        proc.wait(15)
        reader.join(5)
        proc.stdout.close()
    text = "".join(output)
    for name in ("Squat2StandUp", "move forward", "move rotate", "damp"):
        assert f"Test: {name}" in text, text
    # It ran until its stdin ended (input() then raises EOFError: its only way out), and nothing else failed.
    assert text.count("Traceback") == 1 and text.rstrip().endswith("EOFError: EOF when reading a line"), text


def test_lockstep_walk_is_recorded_and_resimulates_to_zero(start_service, zsession, robot_id, tmp_path):
    """Under `clock: lockstep` the controller is the clock; the recorder sees its commands; resim: 0 divergence."""
    keys = Keys(robot_id)
    domain = unused_domain_id()
    start_service("sim", "--clock", "lockstep")
    odom = Latest(zsession, keys.odom, Odometry)
    odom.wait(timeout_s=60, what="the initial state")
    walking = start_service("loco")  # the walking controller: the sport service forwards to it
    wait_for(lambda: "zensim loco up" in walking.log() or not walking.alive(), 60, "the walking controller to start")
    adapter = start_service("unitree", "--domain-id", str(domain), "--interface", "lo")
    wait_for(lambda: "unitree adapter up" in adapter.log() or not adapter.alive(), 60, "the adapter to start")
    path = tmp_path / "walk.mcap"
    recorder = start_service("record", "-o", str(path))
    wait_for(lambda: "saved the sim's description" in recorder.log() or not recorder.alive(), 30, "the recorder")
    loco = Loco(domain, tmp_path / "loco.log")
    try:
        assert loco.call("SetFsmId", 706) == 0
        odom.wait(lambda m: m.sim_time_s >= 3.0, 120, "3 s of lockstep sim time")
        loco.call("Move", 0.3, 0, 0, True)
        moving = odom.value
        walked = odom.wait(lambda m: m.sim_time_s >= moving.sim_time_s + 3.0, 120, "3 s of walking")
        assert walked.pos[0] - moving.pos[0] > 0.4, (moving.pos, walked.pos)
        loco.call("ZeroTorque")
    finally:
        loco.close()
    walking.signal(signal.SIGTERM)  # stop the clock: no more commands
    walking.proc.wait(15)
    time.sleep(0.5)
    recorder.signal(signal.SIGTERM)
    assert recorder.proc.wait(15) == 0, recorder.log()
    result = subprocess.run([sys.executable, "-m", "zensim", "resim", str(path)], capture_output=True, text=True,
                            timeout=180)
    assert result.returncode == 0, result.stderr
    assert "lockstep recording" in result.stdout, result.stdout
    # Every 20 ms of the ~6 s walk was one of the controller's commands, recorded and re-applied.
    commands = int(re.search(r"(\d+) commands", result.stdout).group(1))
    assert commands >= 250, result.stdout
    assert "joint position 0 rad, base position 0 m, base orientation 0 rad" in result.stdout, result.stdout


def test_bad_sport_requests_and_arm_sdk_samples_are_refused_counted_and_survived(lockstep_stack):
    """Bad parameters get 3204 and change nothing; bad rt/arm_sdk samples are counted and never move the arms."""
    from cyclonedds._clayer import ddspy_write
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from unitree_sdk import low_cmd_crc, new_low_cmd
    from zensim.unitree.idl import LowCmd_

    stack = lockstep_stack
    loco = Loco(stack.domain, stack.tmp / "loco-bad.log")
    try:
        stand_up(stack, loco)
        assert loco.call("SetFsmId", "x") == 3204
        assert loco.call("SetVelocity", "a", 0, 0, 1.0) == 3204
        assert loco.call("SetVelocity", 0.3, 0, 0, -1.0) == 3204
        assert loco.call("SetBalanceMode", 7) == 3204
        assert loco.call("GetFsmId") == [0, 706]  # nothing changed
        before = stack.unitree.wait(what="a status")
        participant = stack.switcher.participant
        writer = DataWriter(participant, Topic(participant, "rt/arm_sdk", LowCmd_))
        elbow_up = new_low_cmd()
        elbow_up.motor_cmd[29].q = 1.0  # full weight
        elbow_up.motor_cmd[18].q, elbow_up.motor_cmd[18].kp, elbow_up.motor_cmd[18].kd = 1.2, 60.0, 1.5
        nan = new_low_cmd()
        nan.motor_cmd[29].q, nan.motor_cmd[18].q = 1.0, float("nan")
        negative = new_low_cmd()
        negative.motor_cmd[29].q, negative.motor_cmd[18].kp = 1.0, -5.0
        good = new_low_cmd().serialize()
        elbow_up.crc = 0x12345678  # a wrong CRC: ignored, as the robot does
        for cmd in (nan, negative):
            cmd.crc = low_cmd_crc(cmd)

        def counted() -> bool:  # a new writer's first samples may go before discovery matched it: resend
            for cmd in (elbow_up, nan, negative):
                writer.write(cmd)
            ddspy_write(writer._ref, good[:100])  # not a LowCmd_ at all
            status = stack.unitree.value
            return status.arm_sdk_rejected - before.arm_sdk_rejected >= 40

        wait_for(counted, 30, "the bad arm_sdk samples counted", 0.01)
        after = stack.unitree.value
        assert after.arm_sdk_received - after.arm_sdk_rejected == before.arm_sdk_received - before.arm_sdk_rejected
        stack.run_for(1.0)
        assert abs(stack.odom.value.pos[2] - 0.76) < 0.05  # still standing on the policy
        joints = Latest(stack.session, stack.keys.joints, JointState)
        assert abs(joints.wait(what="a state").q[18]) < 0.1  # no bad sample moved the elbow
        assert stack.up.poll() is None
        stack.unitree.wait(lambda u: u.policy_steps > before.policy_steps, 10, "the policy still stepping")
        assert "not applied" in stack.log_path.read_text()  # logged (rate-limited), not silent
    finally:
        loco.close()


def test_a_sport_request_with_an_integer_past_float_is_refused_and_every_later_request_obeyed(lockstep_stack):
    """Issue 27 item 1: `{"data": 1000...0}` (400 digits) killed the adapter's DDS thread (OverflowError);
    the robot walked on, StopMove and Damp were ignored, and the status said all was well. Now it is a
    3204 like any bad parameter, and the same thread goes on serving the calls after it."""
    stack = lockstep_stack
    loco = Loco(stack.domain, stack.tmp / "loco-huge.log")
    try:
        stand_up(stack, loco)
        assert loco.call("Move", 0.3, 0, 0, True) is None  # walking, for 864000 s
        stack.run_for(1.0)
        huge = "1" + "0" * 400
        assert loco.call("_CallBase", 7101, '{"data": %s}' % huge, 0, 0)[0] == 3204
        assert loco.call("_CallBase", 7105, '{"velocity": [%s, 0, 0], "duration": 1}' % huge, 0, 0)[0] == 3204
        assert loco.call("GetFsmId") == [0, 706]  # answered: the thread lives, nothing changed
        assert loco.call("SetVelocity", 0.0, 0.0, 0.0) == 0  # StopMove
        settled = stack.run_for(1.0)
        later = stack.run_for(3.0)
        assert math.dist(settled.pos[:2], later.pos[:2]) < 0.25, (settled.pos, later.pos)  # it stopped
        loco.call("Damp")
        folded = stack.run_for(3.0)
        assert folded.pos[2] < later.pos[2] - 0.15, (later.pos, folded.pos)
        status = stack.unitree.wait(lambda u: u.loco_fsm_id == 1, 10, "the status to say damp")
        assert status.internal_errors == 0 and stack.up.poll() is None
    finally:
        loco.close()


def test_one_absurd_arm_sdk_command_is_refused_alone_and_the_walk_goes_on(lockstep_stack):
    """Issue 27 item 2: one rt/arm_sdk command with kp 1e6 (or q 1e30) at weight 1 was blended into every
    command of the walk; the sim refused them all and the G1 fell. Now that command alone is refused
    (counted) and the walk's commands go on being applied."""
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from unitree_sdk import low_cmd_crc, new_low_cmd
    from zensim.unitree.idl import LowCmd_

    stack = lockstep_stack
    loco = Loco(stack.domain, stack.tmp / "loco-arm-bad.log")
    try:
        stand_up(stack, loco)
        loco.call("Move", 0.3, 0, 0, True)
        stack.run_for(0.5)
        participant = stack.switcher.participant
        writer = DataWriter(participant, Topic(participant, "rt/arm_sdk", LowCmd_))
        stiff, far = new_low_cmd(), new_low_cmd()
        for cmd in (stiff, far):
            cmd.motor_cmd[29].q = 1.0  # full weight
            cmd.motor_cmd[18].q, cmd.motor_cmd[18].kp, cmd.motor_cmd[18].kd = 0.3, 60.0, 1.5
        stiff.motor_cmd[18].kp = 1e6
        far.motor_cmd[18].q = 1e30
        for cmd in (stiff, far):
            cmd.crc = low_cmd_crc(cmd)
        before = stack.unitree.wait(what="a status")
        sim_before = stack.status.wait(what="the sim's status")
        first_status = len(stack.status.history)

        def taken() -> bool:  # a new writer's first samples may go before discovery matched it: resend
            for cmd in (stiff, far):
                writer.write(cmd)
            status = stack.unitree.value
            return status.arm_sdk_received - before.arm_sdk_received >= 2

        wait_for(taken, 30, "the absurd arm_sdk commands read", 0.05)
        start = stack.odom.value
        walked = stack.run_for(3.0)
        assert walked.pos[0] - start.pos[0] > 0.3, (start.pos, walked.pos)  # still walking
        assert walked.pos[2] > 0.6 and not stack.fell_since(first_status), walked.pos
        sim_after = stack.status.wait(lambda s: s.sim_time_s > walked.sim_time_s, 20, "a newer sim status")
        assert sim_after.rejected_commands == sim_before.rejected_commands  # nothing poisoned reached the sim
        # The walking controller's refusals reach the adapter's status with the controller's next state:
        # wait for the counts to agree (none of the absurd commands was applied).
        applied_before = before.arm_sdk_received - before.arm_sdk_rejected
        after = stack.unitree.wait(lambda u: u.arm_sdk_received - u.arm_sdk_rejected == applied_before, 10,
                                   f"every absurd arm_sdk command counted as refused (before: {before})")
        assert after.arm_sdk_rejected - before.arm_sdk_rejected >= 2  # refused, counted
        loco.call("StopMove")
    finally:
        loco.close()
