"""`zensim course`: the standard course, every item over a few seeds, scored into one table.

Reads/writes: what `zensim scenario` does (zensim/scenario.py), for each run; starts and stops the processes
of each run: a lockstep `zensim sim` on the item's terrain and (by default) `zensim loco`, the reference
controller, on a private `zensim router`. Writes course.md and course.json (and, with --record, an MCAP
per run) into --output-dir.

Items: flat ground, a slope up, stairs up, stairs down, rough ground, a push from each of four sides at
rising force (40, 80, 120 N for 0.2 s) while walking, and four that need the sim's ctl/faults (a weak
left knee, IMU noise, encoder noise, 20 ms of command delay): without it their rows say the sim does not serve it.
A seed moves the item's events by a fraction of a gait cycle and makes the rough ground.

`--controller external` runs your controller instead: it must be running, connected to the router given
by `--zenoh-connect`, under `--robot-id`, driving the sim by `cmd/motors` (lockstep: each command
advances the sim 20 ms, so the controller is the clock) and following `cmd/velocity` if it walks. The
course starts one sim per run there; your controller sees a new sim (`run_id`) at each.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Annotated, ClassVar, Final, Literal

import msgspec
import zenoh

from zensim.common.entry import fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import CommonSettings, ZenohSettings, settings_or_exit
from zensim.common.wire import error_text
from zensim.schemas import Keys, Variant

from .check import is_alive
from .course_plot import course_svg
from .scenario import Recording, ScenarioRunner, zenoh_env
from .scenario_file import AnyEvent, Faults, Loco, Push, Scenario, ScenarioError, Velocity
from .scenario_score import ScenarioResult

logger = logging.getLogger("zensim.course")

PROG = "zensim course"
GAIT_S: Final = 0.8
"""The G1 policy's gait cycle: seeds shift events by fractions of it, so each seed meets another phase."""
WALK_AT_S: Final = 3.0
"""Stand-up (from the squat) takes 2.5 s of sim time: walking starts after it."""
PUSH_FORCES_N: Final = (40.0, 80.0, 120.0)
PUSH_SIDES: Final = {"front": (-1.0, 0.0, 0.0), "back": (1.0, 0.0, 0.0), "left": (0.0, -1.0, 0.0), "right": (0.0, 1.0, 0.0)}
"""Where the push comes from -> the force's direction (a push from the front drives the robot back)."""


@dataclass(frozen=True)
class Item:
    """One course item: its terrain (TOML for `zensim sim --terrain`, empty: flat) and its events for a seed."""

    name: str
    what: str
    terrain: Callable[[int], str]
    events: Callable[[float], list[AnyEvent]]
    end_s: float
    needs_faults: bool = False


def _flat(seed: int) -> str:
    return ""


def _walk(vx: float) -> Callable[[float], list[AnyEvent]]:
    return lambda shift: [Velocity(at_s=WALK_AT_S + shift, vx=vx)]


def _pushes(direction: tuple[float, float, float]) -> Callable[[float], list[AnyEvent]]:
    def events(shift: float) -> list[AnyEvent]:
        walk: list[AnyEvent] = [Velocity(at_s=WALK_AT_S, vx=0.3)]
        return walk + [Push(at_s=5.0 + 3.0 * k + shift, direction=direction, magnitude_n=force, duration_s=0.2)
                       for k, force in enumerate(PUSH_FORCES_N)]
    return events


def _fault(request: dict[str, object]) -> Callable[[float], list[AnyEvent]]:
    return lambda shift: [Velocity(at_s=WALK_AT_S, vx=0.4), Faults(at_s=4.0 + shift, request=request)]


ITEMS: Final[tuple[Item, ...]] = (
    Item("flat", "walk 0.5 m/s on the floor", _flat, _walk(0.5), 11.0),
    Item("slope", "walk 0.4 m/s up an 8 degree slope", lambda seed: """
[[features]]
type = "slope"
angle_deg = 8
length_m = 3.0
top_m = 2.0
width_m = 3.0
at = [1.0, 0.0]
""", _walk(0.4), 13.0),
    Item("stairs_up", "walk 0.4 m/s up 4 steps of 5 cm", lambda seed: """
[[features]]
type = "stairs"
step_height_m = 0.05
step_depth_m = 0.35
count = 4
way = "up"
width_m = 3.0
landing_m = 2.0
at = [1.0, 0.0]
""", _walk(0.4), 13.0),
    Item("stairs_down", "walk 0.4 m/s down 4 steps of 5 cm", lambda seed: """
[[features]]
type = "stairs"
step_height_m = 0.05
step_depth_m = 0.35
count = 4
way = "down"
width_m = 3.0
landing_m = 1.5
at = [-0.75, 0.0]
""", _walk(0.4), 13.0),
    Item("rough", "walk 0.4 m/s over 3 cm rough ground", lambda seed: f"""
[[features]]
type = "rough"
size_m = [8.0, 4.0]
amplitude_m = 0.03
cell_m = 0.1
seed = {seed}
at = [2.5, 0.0]
""", _walk(0.4), 13.0),
    *(Item(f"push_{side}", f"walk 0.3 m/s, pushed from the {side} at 40, 80, 120 N for 0.2 s", _flat, _pushes(d), 15.0)
      for side, d in PUSH_SIDES.items()),
    Item("weak_knee", "walk 0.4 m/s, left knee at 60 % torque (ctl/faults)", _flat,
         _fault({"verb": "set", "joints": [{"joint": "left_knee_joint", "torque_scale": 0.6}]}), 11.0,
         needs_faults=True),
    Item("imu_noise", "walk 0.4 m/s, IMU gyro noise 0.05 rad/s and accelerometer noise 0.5 m/s^2 (ctl/faults)",
         _flat, _fault({"verb": "set", "sensors": {"gyro_noise_std_rad_s": 0.05, "accel_noise_std_m_s2": 0.5},
                        "seed": 1}), 11.0, needs_faults=True),
    Item("joint_noise", "walk 0.4 m/s, encoder noise 0.01 rad and 0.2 rad/s (ctl/faults)", _flat,
         _fault({"verb": "set", "sensors": {"q_noise_std_rad": 0.01, "dq_noise_std_rad_s": 0.2}, "seed": 1}), 11.0,
         needs_faults=True),
    # 10 of the G1's 2 ms steps: under the course's lockstep (20 ms per command) each command lands one advance late.
    Item("command_delay", "walk 0.4 m/s, 20 ms (10 steps) of command delay (ctl/faults)", _flat,
         _fault({"verb": "set", "link": {"command_delay_steps": 10}}), 11.0, needs_faults=True),
    # The same 20 ms the other way: each state the controller gets describes the instant one advance before.
    Item("state_delay", "walk 0.4 m/s, 20 ms (10 steps) of state delay (ctl/faults)", _flat,
         _fault({"verb": "set", "link": {"state_delay_steps": 10}}), 11.0, needs_faults=True),
    Item("imu_drift", "walk 0.4 m/s, the IMU's heading drifting 0.05 rad/s (ctl/faults)", _flat,
         _fault({"verb": "set", "sensors": {"orientation_drift_rad_s": 0.05}}), 11.0, needs_faults=True),
)
ITEM_NAMES: Final = tuple(item.name for item in ITEMS)


class CourseSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim course`."""

    env_prefix: ClassVar[str] = "COURSE"
    items: tuple[str, ...] = ()
    """Course items to run, comma-separated (default all): flat, slope, stairs_up, stairs_down, rough,
    push_front, push_back, push_left, push_right, weak_knee, imu_noise, joint_noise, command_delay."""
    seeds: Annotated[int, msgspec.Meta(ge=1, le=100)] = 3
    """Seeds per item."""
    controller: Literal["loco", "external"] = "loco"
    """loco: the course runs `zensim loco` (the reference) for each run; external: yours, already running."""
    output_dir: str = "course-results"
    """Where course.md, course.json (and with --record the MCAPs) go."""
    record: bool = False
    """Record each run into an MCAP in --output-dir."""
    stall_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 20.0
    """Wall time without a new state after which a run stops (a controller that stopped driving the sim), s."""
    start_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 60.0
    """Wall time for each run's sim (and controller) to come up, s."""
    variants: bool = False
    """Run each seed on its own variant of the robot: a ctl/reset `randomize` with the run's seed, friction x 0.6-1.4,
    link masses x 0.9-1.1, centres of mass moved up to 1 cm, motors at 85-100 % (the row says its mass)."""

    def __post_init__(self) -> None:
        unknown = [name for name in self.items if name not in ITEM_NAMES]
        if unknown:
            raise ValueError(f"unknown course items {unknown}; the course has {', '.join(ITEM_NAMES)}")


class Row(msgspec.Struct, frozen=True, kw_only=True):
    """One run of the course: an item, a seed and its result (or why it did not run)."""

    item: str
    seed: int
    result: ScenarioResult | None = None
    skipped: str = ""
    variant: Variant | None = None
    """With --variants: the robot the run drew (its factors and mass)."""


VARIANT_RANGES: Final = {"friction": (0.6, 1.4), "mass": (0.9, 1.1), "com_offset_m": 0.01, "motor_strength": (0.85, 1.0)}
"""--variants: what each seed's robot may differ by (ResetRequest.randomize): a floor wetter or grippier, links a
tenth lighter or heavier with their centres of mass a little off, motors up to 15 % weak."""


class Processes:
    """Child processes of a run, stopped in reverse order."""

    def __init__(self, env: dict[str, str], log_dir: str) -> None:
        self.env = env
        self.log_dir = log_dir
        self.procs: list[tuple[str, subprocess.Popen[bytes]]] = []

    def start(self, command: str, *args: str) -> subprocess.Popen[bytes]:
        log = open(os.path.join(self.log_dir, f"{command}-{len(self.procs)}.log"), "wb")
        proc = subprocess.Popen([sys.executable, "-m", "zensim", command, *args], env=self.env, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        self.procs.append((command, proc))
        return proc

    def stop(self) -> None:
        for _, proc in reversed(self.procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for _, proc in reversed(self.procs):
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        self.procs.clear()


def scenario_of(item: Item, seed: int, controller: str) -> Scenario:
    """The item's timeline for one seed; the reference controller is first told to stand and walk."""
    shift = round((seed * 0.37) % 1.0 * GAIT_S, 3)
    events = item.events(shift)
    if controller == "loco":
        events = [Loco(at_s=0.0, verb="walk"), *events]
    return Scenario(end_s=item.end_s + shift, events=sorted(events, key=lambda e: e.at_s), name=f"{item.name}-s{seed}")


def run_item(session: zenoh.Session, settings: CourseSettings, item: Item, seed: int, env: dict[str, str],
             stop: threading.Event, work: str) -> Row:
    """One run: its sim (and the reference controller), the scenario, the processes stopped."""
    keys = Keys(settings.robot_id)
    scenario = scenario_of(item, seed, settings.controller)
    sim_args = ["--clock", "lockstep"]
    terrain = item.terrain(seed)
    if terrain:
        path = os.path.join(work, f"{item.name}-{seed}.toml")
        with open(path, "w") as file:
            file.write(terrain)
        sim_args += ["--terrain", path]
    processes = Processes(env, work)
    recorder: Recording | None = None
    try:
        processes.start("sim", *sim_args)
        if settings.controller == "loco":
            processes.start("loco")
            if not is_alive(session, keys.alive("loco"), settings.start_timeout_s):
                return Row(item=item.name, seed=seed, skipped="zensim loco did not come up")
        runner = ScenarioRunner(session, keys, scenario)
        try:
            runner.check_robot(settings.start_timeout_s)
        except ScenarioError as exc:
            if item.needs_faults and "ctl/faults" in str(exc):
                return Row(item=item.name, seed=seed, skipped="the sim does not serve ctl/faults")
            return Row(item=item.name, seed=seed, skipped=str(exc))
        variant = None
        if settings.variants:  # before the scenario starts: a lockstep sim waits at 0 s for its controller
            try:
                reply = reset_robot(session, keys, {"randomize": {"seed": seed, **VARIANT_RANGES}})
            except ValueError as exc:
                return Row(item=item.name, seed=seed, skipped=f"the variant was refused: {exc}")
            variant = msgspec.convert(reply["variant"], Variant)
        recording = os.path.join(settings.output_dir, f"{scenario.name}.mcap") if settings.record else ""
        if recording:
            recorder = Recording(recording, settings.robot_id, ZenohSettings(mode="client", connect=(env["ZENSIM_ZENOH_CONNECT"],)))
        result = runner.run(stop, settings.stall_timeout_s, settings.start_timeout_s, recording)
        return Row(item=item.name, seed=seed, result=result, variant=variant)
    finally:
        if recorder is not None:
            recorder.stop()
        processes.stop()


def reset_robot(session: zenoh.Session, keys: Keys, request: dict[str, object]) -> dict:
    """ctl/reset with `request`; its reply.

    Raises:
        ValueError: no reply, or the sim refused it (its reason).
    """
    for reply in session.get(keys.ctl("reset"), payload=json.dumps(request), timeout=10.0):
        answer = json.loads(reply.ok.payload.to_bytes()) if reply.ok is not None else {"error": error_text(reply.err)}
        if not answer.get("ok"):
            raise ValueError(str(answer.get("error"))[:200])
        return answer
    raise ValueError("no reply on ctl/reset")


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def row_cells(row: Row) -> list[str]:
    """A table row: item, seed, survived, distance, tracking error, push recoveries, peak torque, note."""
    r = row.result
    if r is None:
        return [row.item, str(row.seed), "-", "-", "-", "-", "-", f"skipped: {row.skipped}"]
    recoveries = " / ".join("no" if p.recovered_s is None else f"{p.recovered_s:.2f}" for p in r.pushes) or "-"
    notes = [r.note] if r.note else []
    if row.variant is not None:
        notes.append(f"variant {row.variant.seed}: {row.variant.mass_kg:.1f} kg, friction x {row.variant.friction_scale:.2f}")
    notes += [f"{e.type} at {e.at_s:g} s refused: {e.error}" for e in r.events if not e.ok]
    survived = "yes" if r.survived else "-" if r.fell_at_s is None else f"no ({r.fell_at_s:.1f} s)"
    return [row.item, str(row.seed), survived, f"{r.distance_m:.2f}", _fmt(r.tracking_error_m_s, ".3f"), recoveries,
            f"{r.peak_torque_nm:.0f} ({r.peak_torque_joint.removesuffix('_joint')})", "; ".join(notes)[:160]]


HEADER: Final = ["item", "seed", "survived", "distance m", "tracking error m/s", "push recovery s", "peak torque N m", "note"]


def summary(rows: Sequence[Row]) -> list[list[str]]:
    """Per item: runs survived, mean distance and tracking error, the slowest recovery, the largest torque."""
    table = []
    for name in dict.fromkeys(row.item for row in rows):
        results = [row.result for row in rows if row.item == name and row.result is not None]
        if not results:
            table.append([name, "skipped", "-", "-", "-", "-"])
            continue
        errors = [r.tracking_error_m_s for r in results if r.tracking_error_m_s is not None]
        recoveries = [p.recovered_s for r in results for p in r.pushes]
        slowest = ("-" if not recoveries else "not recovered" if None in recoveries
                   else f"{max(p for p in recoveries if p is not None):.2f}")
        table.append([name, f"{sum(r.survived for r in results)}/{len(results)}",
                      f"{sum(r.distance_m for r in results) / len(results):.2f}",
                      _fmt(sum(errors) / len(errors) if errors else None, ".3f"), slowest,
                      f"{max(r.peak_torque_nm for r in results):.0f}"])
    return table


SUMMARY_HEADER: Final = ["item", "survived", "mean distance m", "mean tracking error m/s", "slowest push recovery s", "peak torque N m"]


def markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def plain(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in rows]
    return "\n".join(lines)


ROW_WIDTHS: Final = (14, 4, 12, 10, 18, 20, 22)


def _line(cells: Sequence[str]) -> str:
    """A row printed as it comes, in fixed columns (the last, the note, runs on)."""
    return "  ".join([c.ljust(w) for c, w in zip(cells, ROW_WIDTHS)] + list(cells[len(ROW_WIDTHS):])).rstrip()


def run_course(session: zenoh.Session, settings: CourseSettings, stop: threading.Event, endpoint: str) -> int:
    items = [item for item in ITEMS if not settings.items or item.name in settings.items]
    env = {k: v for k, v in os.environ.items() if not k.startswith("ZENSIM_")}
    env.update(zenoh_env(ZenohSettings(mode="client", connect=(endpoint,))), ZENSIM_ROBOT_ID=settings.robot_id,
               ZENSIM_LOG_LEVEL="INFO", PYTHONUNBUFFERED="1")
    os.makedirs(settings.output_dir, exist_ok=True)
    rows: list[Row] = []
    started = time.monotonic()
    print(_line(HEADER), flush=True)
    with tempfile.TemporaryDirectory(prefix="zensim-course-") as work:
        for item in items:
            for seed in range(settings.seeds):
                if stop.is_set():
                    break
                row = run_item(session, settings, item, seed, env, stop, work)
                rows.append(row)
                print(_line(row_cells(row)), flush=True)
                if row.skipped == "the sim does not serve ctl/faults":
                    break  # every seed would say the same
    took = time.monotonic() - started
    md = "\n".join([f"# zensim course: controller `{settings.controller}`", "",
                    f"{len(rows)} runs, {settings.seeds} seed(s) per item, lockstep, in {took:.0f} s of wall time.", "",
                    markdown(SUMMARY_HEADER, summary(rows)), "", markdown(HEADER, [row_cells(r) for r in rows]), ""])
    with open(os.path.join(settings.output_dir, "course.md"), "w") as file:
        file.write(md)
    with open(os.path.join(settings.output_dir, "course.json"), "wb") as file:
        file.write(msgspec.json.format(msgspec.json.encode({"controller": settings.controller, "seeds": settings.seeds,
                                                             "wall_s": round(took, 1), "runs": rows})))
    with open(os.path.join(settings.output_dir, "course.svg"), "w") as file:
        file.write(course_svg(rows, f"zensim course: controller {settings.controller}, {settings.seeds} seed(s) per item"))
    print()
    print(plain(SUMMARY_HEADER, summary(rows)))
    print(f"wrote {os.path.join(settings.output_dir, 'course.md')}, course.json and course.svg")
    return 0 if not stop.is_set() else 1


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def main(argv: Sequence[str] | None = None) -> int:
    settings = settings_or_exit(CourseSettings, sys.argv[1:] if argv is None else argv, PROG)
    setup_logging(settings.log_level)
    if settings.controller == "external":
        if not settings.zenoh.connect:
            return fail(PROG, "--controller external needs --zenoh-connect ENDPOINT: the router your controller uses")
        endpoint = settings.zenoh.connect[0]
        return serve(PROG, settings, lambda session, s, stop: run_course(session, s, stop, endpoint), role="operator")
    # The reference controller: a private router, so the course never meets a stack already running here.
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("ZENSIM_")}
    env.update(ZENSIM_ZENOH_MODE="router", ZENSIM_ZENOH_LISTEN=endpoint, ZENSIM_LOG_LEVEL="WARNING")
    router = subprocess.Popen([sys.executable, "-m", "zensim", "router"], env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while not _listening(endpoint):
            if router.poll() is not None or time.monotonic() > deadline:
                return fail(PROG, "the course's router did not start")
            time.sleep(0.1)
        zenoh_settings = ZenohSettings(mode="client", connect=(endpoint,))
        return serve(PROG, settings, lambda session, s, stop: run_course(session, s, stop, endpoint), role="operator",
                     zenoh_settings=zenoh_settings)
    finally:
        router.send_signal(signal.SIGTERM)
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()


def _listening(endpoint: str) -> bool:
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    try:
        with socket.create_connection((host, int(port)), timeout=0.5):
            return True
    except OSError:
        return False

