"""`zensim scenario FILE`: play a scenario (zensim/scenario_file.py) against whatever controller runs the robot.

Reads:  state/odom, state/sim, state/joints (sim time, fallen, torques), info/robot (joint names)
Writes: ctl/push, ctl/band, ctl/loco, ctl/faults (queries), cmd/velocity (puts); the result (JSON) and,
        with --record, an MCAP made by a `zensim record` process it starts and stops

The scenario follows the sim's clock: time 0 is the first state (or status) it sees. At that moment every
push, band, faults and velocity event is sent ahead with its sim time (`at_s`): the sim keeps each request for
the step that starts at its time, the walking controller each velocity for its tick at that time, so under
lockstep they act at the same step in every run, however the machine is loaded (the same scenario, seed and
commands give the same recording). One that a real-time sim has already passed when it arrives is sent again
to act at once (the result says when it did). A velocity holds until the next velocity event or the end. The
loco verbs fire when a state at or past their time arrives (the first, at 0 s, while a lockstep sim waits).
Before anything is sent the scenario is checked whole, and so is the robot's side: a `loco` event with no
walking controller serving ctl/loco, or a `faults` event with a sim that does not serve ctl/faults, is
refused with one line. The run ends at end_s, or early (said in the result) when the sim stalls for
--stall-timeout-s of wall time, goes back in time (a reset) or restarts.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from typing import Annotated, Any, ClassVar, Final

import msgspec
import zenoh

from zensim.common.entry import fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import CommonSettings, ZenohSettings, settings_or_exit
from zensim.common.wire import error_text, payload_of
from zensim.schemas import Codec, DecodeError, JointState, Keys, Odometry, RobotInfo, SimStatus

from .replay import leading_file_argument
from .scenario_file import AnyEvent, Band, Faults, Loco, Push, Scenario, ScenarioError, Velocity, load_scenario
from .scenario_score import EventOutcome, ScenarioResult, Trace, result_lines, score

logger = logging.getLogger("zensim.scenario")

PROG = "zensim scenario"
QUERY_TIMEOUT_S: Final = 5.0
MAX_QUEUED: Final = 100_000
SERVED_WAIT_S: Final = 3.0
"""How long the check for a ctl/loco or ctl/faults server waits for the router's declarations."""


class ScenarioSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim scenario FILE`."""

    env_prefix: ClassVar[str] = "SCENARIO"
    file: str = ""
    """The scenario file (TOML; the first argument)."""
    result: str = ""
    """Write the result here as JSON; empty: print only."""
    record: str = ""
    """Also record the run into this MCAP file (a `zensim record` process for the run's length)."""
    stall_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 20.0
    """Wall time without a new state after which the run stops (a lockstep sim whose controller stopped), s."""
    start_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 30.0
    """Wall time to wait for the sim to answer info/robot and send its first state, s."""


def ctl_faults_key(keys: Keys) -> str:
    """ctl/faults, from the topic registry once the sim serves it there; its place until then."""
    return str(getattr(keys, "ctl_faults", f"{keys.root}/ctl/faults"))


def zenoh_env(zenoh_settings: ZenohSettings) -> dict[str, str]:
    """The ZENSIM_ZENOH_* variables (and ZENSIM_SECURE_DIR) that put a child process on the same network."""
    env = {"ZENSIM_ZENOH_MODE": zenoh_settings.mode, "ZENSIM_ZENOH_CONNECT": ",".join(zenoh_settings.connect),
           "ZENSIM_ZENOH_LISTEN": "", "ZENSIM_ZENOH_MULTICAST_SCOUTING": str(zenoh_settings.multicast_scouting).lower()}
    if zenoh_settings.config_file:
        env["ZENSIM_ZENOH_CONFIG_FILE"] = zenoh_settings.config_file
    if zenoh_settings.secure_dir:
        env["ZENSIM_SECURE_DIR"] = zenoh_settings.secure_dir
    return env


class Recording:
    """A `zensim record` process for the length of a run."""

    def __init__(self, output: str, robot_id: str, zenoh_settings: ZenohSettings, timeout_s: float = 30.0) -> None:
        self.output = output
        env = {k: v for k, v in os.environ.items() if not k.startswith("ZENSIM_")}
        env.update(zenoh_env(zenoh_settings), ZENSIM_ROBOT_ID=robot_id, ZENSIM_LOG_LEVEL="INFO", PYTHONUNBUFFERED="1")
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "zensim", "record", "-o", output], env=env,
                                     stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while b"recording zensim/" not in self.log():  # logged once its subscriber is declared
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                raise ScenarioError(f"zensim record did not start: {self.log()[-300:].decode(errors='replace').strip()}")
            time.sleep(0.05)

    def log(self) -> bytes:
        self._log.seek(0)
        return self._log.read()

    def stop(self) -> None:
        """Ctrl-C it (the file is finished and indexed) and wait."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._log.close()


class ScenarioRunner:
    """Plays one scenario: states arrive on zenoh's threads, the caller's thread fires events and scores."""

    def __init__(self, session: zenoh.Session, keys: Keys, scenario: Scenario) -> None:
        self.session = session
        self.keys = keys
        self.scenario = scenario
        self.states: queue.Queue[tuple[str, object]] = queue.Queue(MAX_QUEUED)
        self.joint_names: tuple[str, ...] = ()
        self.fall_tilt_rad: float | None = None
        """The sim's fall threshold (RobotInfo): falls are judged on the states, at their own sim time."""
        self._codecs: dict[str, Codec[Any]] = {keys.odom: Codec(Odometry), keys.sim_status: Codec(SimStatus), keys.joints: Codec(JointState)}
        self._subscribers: list[zenoh.Subscriber] = []
        self._fired: list[AnyEvent] = []
        """The events fired so far, in the order their outcomes were recorded."""

    def check_robot(self, timeout_s: float) -> None:
        """The sim answers, and serves every verb the scenario uses; else one line saying what is missing.

        Raises:
            ScenarioError: no sim, or a verb nobody serves.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                info = self._query(self.keys.robot_info + "?format=json", None, 2.0)
                robot = msgspec.json.decode(info, type=RobotInfo)
                self.joint_names, self.fall_tilt_rad = robot.joint_names, robot.fall_tilt_rad
                break
            except (TimeoutError, ValueError, zenoh.ZError, msgspec.DecodeError) as exc:
                if time.monotonic() > deadline:
                    raise ScenarioError(f"no sim answers for robot {self.keys.robot!r} ({exc})") from None
                time.sleep(0.2)
        types = {type(e) for e in self.scenario.events}
        if Loco in types and not self._served(self.keys.ctl_loco):
            raise ScenarioError("the scenario has loco events, but no walking controller serves ctl/loco "
                                f"for robot {self.keys.robot!r} (start `zensim loco`)")
        if Faults in types and not self._served(ctl_faults_key(self.keys)):
            raise ScenarioError(f"the scenario has faults events, but the sim of robot {self.keys.robot!r} "
                                "does not serve ctl/faults")

    def _served(self, key: str) -> bool:
        querier = self.session.declare_querier(key)
        try:
            deadline = time.monotonic() + SERVED_WAIT_S
            # zenoh-python 1.x answers a MatchingStatus (its stubs say bool): read it either way.
            while not bool(getattr(querier.matching_status, "matching", querier.matching_status)):
                if time.monotonic() > deadline:
                    return False
                time.sleep(0.05)
            return True
        finally:
            querier.undeclare()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            self.states.put_nowait((key, self._codecs[key].decode(*payload_of(sample))))
        except (KeyError, DecodeError, queue.Full):
            pass  # not ours to judge: the sim counts its own; a full queue only thins a trace

    def _query(self, key: str, payload: object, timeout_s: float = QUERY_TIMEOUT_S) -> bytes:
        body = None if payload is None else json.dumps(payload)
        for reply in self.session.get(key, payload=body, timeout=timeout_s):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            raise ValueError(error_text(reply.err))
        raise TimeoutError(f"no reply on {key}")

    def run(self, stop: threading.Event, stall_timeout_s: float, start_timeout_s: float, recording: str = "") -> ScenarioResult:
        """Play the scenario to its end (or until it cannot go on) and score it."""
        self._subscribers = [self.session.declare_subscriber(k, self._on_sample) for k in self._codecs]
        try:
            return self._play(stop, stall_timeout_s, start_timeout_s, recording)
        finally:
            for subscriber in self._subscribers:
                subscriber.undeclare()

    def _play(self, stop: threading.Event, stall_timeout_s: float, start_timeout_s: float, recording: str) -> ScenarioResult:
        trace = Trace(fall_tilt_rad=self.fall_tilt_rad)
        pending = list(self.scenario.events)
        outcomes: list[EventOutcome] = []
        pushes: list[tuple[float, tuple[float, ...], float]] = []
        t0: float | None = None
        run_id = episode = ""
        started = False
        first_wall: float | None = None
        note = ""
        last_state = time.monotonic()
        timeout_s = start_timeout_s
        now = 0.0
        while not stop.is_set():
            try:
                key, message = self.states.get(timeout=0.1)
            except queue.Empty:
                if time.monotonic() - last_state > timeout_s:
                    note = (f"no new state for {timeout_s:g} s of wall time at {now:.2f} s: "
                            "is a controller driving the (lockstep) sim?")
                    break
                continue
            if isinstance(message, SimStatus):
                if (run_id and message.run_id != run_id) or (episode and message.episode != episode):
                    note = f"the sim {'restarted' if message.run_id != run_id else 'reset'} at {now:.2f} s"
                    break
                run_id, episode = message.run_id, message.episode
                if t0 is None:  # a lockstep sim waiting for its first command publishes only its status
                    t0 = message.sim_time_s
                    self._schedule(pending, t0, outcomes, pushes, trace)
                if message.fallen:
                    trace.fallen(max(0.0, message.sim_time_s - t0))
                t = message.sim_time_s - t0
                if trace.times or t < now or (t == now and started):
                    # Once states flow they are the clock: a status goes at 10 Hz of wall time, and under lockstep
                    # its sim time runs ahead of the states read so far (it ended a run one state early, once).
                    continue
            elif isinstance(message, JointState):
                trace.add_torques(message.tau)
                continue
            else:
                assert isinstance(message, Odometry)
                if t0 is None:
                    t0 = message.sim_time_s
                    self._schedule(pending, t0, outcomes, pushes, trace)
                t = message.sim_time_s - t0
                if trace.times and t < trace.times[-1] - 1e-9:
                    note = f"sim time went back at {trace.times[-1]:.2f} s (a reset)"
                    break
                trace.add_odometry(t, message.pos, message.quat_wxyz)
                if t < now:
                    continue  # a status took the clock here before the states came: the state only adds to the trace
            last_state, timeout_s, now, started = time.monotonic(), stall_timeout_s, t, True
            first_wall = first_wall or last_state
            self._due(pending, t, t0, outcomes, pushes, trace)
            if t >= self.scenario.end_s:
                break
        if any(isinstance(e, Velocity) for e in self.scenario.events):  # the scenario's command ends with it
            self.session.put(self.keys.velocity, msgspec.json.encode(Velocity(at_s=0).command(0.0)))
        completed = t0 is not None and now >= self.scenario.end_s
        if stop.is_set() and not completed:
            note = "interrupted"
        if not trace.times:
            trace.add_odometry(0.0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
            note = note or "no state came"
        wall_s = last_state - first_wall if first_wall is not None else 0.0
        # In the file's order (the scheduled events were sent before the loco verbs of the same time).
        place = {id(event): index for index, event in enumerate(self.scenario.events)}
        outcomes = [o for _, o in sorted(zip(self._fired, outcomes), key=lambda pair: place[id(pair[0])])]
        return score(trace, self.scenario.name, pushes, self.joint_names, completed, outcomes, note, recording, wall_s)

    def _hold(self, velocity: Velocity, t: float) -> float:
        """How long a velocity put at scenario time `t` holds: until the next velocity event, or the end."""
        later = [e.at_s for e in self.scenario.events if isinstance(e, Velocity) and e.at_s > velocity.at_s]
        return max(0.0, min(later + [self.scenario.end_s]) - t)

    def _schedule(self, pending: list, t0: float, outcomes: list[EventOutcome],
                  pushes: list[tuple[float, tuple[float, ...], float]], trace: Trace) -> None:
        """At the start: send every event the sim (push, band, faults) or the walking controller (velocity) can
        keep for its sim time (`at_s`), so that each acts at the same step in every run; the loco verbs stay in
        `pending`, fired when a state at or past their time comes."""
        for event in [e for e in pending if not isinstance(e, Loco)]:
            pending.remove(event)
            self._record(event, t0, self._fire(event, t0, t0 + event.at_s), outcomes, pushes, trace)

    def _due(self, pending: list, t: float, t0: float, outcomes: list[EventOutcome],
             pushes: list[tuple[float, tuple[float, ...], float]], trace: Trace) -> None:
        """Fire the events due at scenario time `t` (the loco verbs: the rest went ahead, `_schedule`)."""
        while pending and pending[0].at_s <= t:
            event = pending.pop(0)
            self._record(event, t0, self._fire(event, t0), outcomes, pushes, trace, t)

    def _record(self, event: AnyEvent, t0: float, fired: tuple[EventOutcome, tuple[float, tuple[float, ...], float] | None],
                outcomes: list[EventOutcome], pushes: list[tuple[float, tuple[float, ...], float]], trace: Trace,
                t: float | None = None) -> None:
        outcome, applied = fired
        outcomes.append(outcome)
        self._fired.append(event)
        if applied is not None:
            pushes.append(applied)
        if isinstance(event, Velocity) and outcome.ok:
            trace.command(event.at_s if t is None else t, (event.vx, event.vy, event.wz))

    def _fire(self, event: AnyEvent, t0: float,
              at_s: float | None = None) -> tuple[EventOutcome, tuple[float, tuple[float, ...], float] | None]:
        """Send one event, to act at sim time `at_s` (None: now); a refusal is reported in the result, and the run
        goes on. One the sim refuses because its time has passed (a real-time sim ran on while the request
        travelled) is sent again to act now, and its outcome says when it did."""
        kind = event.__struct_config__.tag
        applied = None
        fired_s = event.at_s
        try:
            match event:
                case Velocity():
                    # Held from its time until the next velocity event or the end: one put, no lapse between.
                    command = msgspec.structs.replace(event.command(self._hold(event, event.at_s)), at_s=at_s)
                    self.session.put(self.keys.velocity, msgspec.json.encode(command))
                    reply: dict = {"ok": True}
                case Push():
                    reply = self._ctl(self.keys.ctl_push, msgspec.to_builtins(event.request()), at_s)
                    push = reply.get("push") or {}
                    if reply.get("ok"):
                        applied = (float(push["start_s"]) - t0, tuple(push["force_n"]), float(push["duration_s"]))
                case Band():
                    reply = self._ctl(self.keys.ctl_band, msgspec.to_builtins(event.request()), at_s)
                case Loco():
                    reply = json.loads(self._query(self.keys.ctl_loco, {"verb": event.verb}))
                    fired_s = float(reply.get("sim_time_s", t0 + event.at_s)) - t0
                case Faults():
                    reply = self._ctl(ctl_faults_key(self.keys), event.request, at_s)
            if reply.get("scheduled_at_s") is not None:
                fired_s = float(reply["scheduled_at_s"]) - t0
            elif not isinstance(event, (Velocity, Loco)) and "sim_time_s" in reply:
                fired_s = float(reply["sim_time_s"]) - t0
        except (TimeoutError, ValueError, KeyError, TypeError, zenoh.ZError) as exc:
            reply = {"ok": False, "error": str(exc)[:240]}
        ok = bool(reply.get("ok"))
        if not ok:
            logger.warning("%s at %.2f s refused: %s", kind, event.at_s, reply.get("error"))
        return EventOutcome(type=str(kind), at_s=event.at_s, fired_s=round(fired_s, 4), ok=ok,
                            error=None if ok else str(reply.get("error"))[:240]), applied

    def _ctl(self, key: str, request: dict, at_s: float | None) -> dict:
        """A ctl request to act at sim time `at_s` (None: now); one whose time passed on its way goes again, now."""
        if at_s is None:
            return json.loads(self._query(key, request))
        reply = json.loads(self._query(key, {**request, "at_s": at_s}))
        if not reply.get("ok") and float(reply.get("sim_time_s", 0.0)) > at_s:
            reply = json.loads(self._query(key, request))
        return reply


def play(session: zenoh.Session, settings: ScenarioSettings, stop: threading.Event, scenario: Scenario,
         keys: Keys | None = None) -> ScenarioResult:
    """Check the robot's side, start the recorder if asked, play, stop the recorder.

    Raises:
        ScenarioError: the robot cannot play this scenario (one line).
    """
    runner = ScenarioRunner(session, keys or Keys(settings.robot_id), scenario)
    runner.check_robot(settings.start_timeout_s)
    recorder = Recording(settings.record, settings.robot_id, settings.zenoh) if settings.record else None
    try:
        return runner.run(stop, settings.stall_timeout_s, settings.start_timeout_s, settings.record)
    finally:
        if recorder is not None:
            recorder.stop()


def write_result(path: str, result: ScenarioResult) -> None:
    with open(path, "wb") as file:
        file.write(msgspec.json.format(msgspec.json.encode(result)))


def run_scenario(session: zenoh.Session, settings: ScenarioSettings, stop: threading.Event, scenario: Scenario) -> int:
    try:
        result = play(session, settings, stop, scenario)
    except ScenarioError as exc:
        return fail(PROG, str(exc))
    for line in result_lines(result):
        print(line, flush=True)
    if settings.result:
        write_result(settings.result, result)
    return 0 if result.completed else 1


def main(argv: Sequence[str] | None = None) -> int:
    args = leading_file_argument(sys.argv[1:] if argv is None else argv)
    settings = settings_or_exit(ScenarioSettings, args, PROG)
    if not settings.file:
        return fail(PROG, "give the scenario: zensim scenario FILE [--result out.json] [--record run.mcap]")
    setup_logging(settings.log_level)
    try:
        scenario = load_scenario(settings.file)
    except ScenarioError as exc:
        return fail(PROG, str(exc))
    # An operator's client: it puts cmd/velocity and asks ctl/* (schemas/topics.py ROLES).
    return serve(PROG, settings, lambda session, s, stop: run_scenario(session, s, stop, scenario), role="operator")
