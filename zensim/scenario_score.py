"""What a scenario run scores, from the states it saw: pure arithmetic, no network.

- survived: the run reached its end and `state/sim` never said `fallen` (and no state showed the base below `FALLEN_HEIGHT_M` of its
  start: a lockstep sim can run ahead of its 10 Hz status, so a fall that a reset undid is still seen).
- distance: the base's horizontal displacement, start to end (state/odom), m.
- tracking error: RMS over the run's windows of |achieved - commanded| horizontal velocity in the heading
  frame, m/s, and of the yaw rate, rad/s; achieved over `WINDOW_S` windows (a step's sway averages out),
  counted only once a velocity was commanded, and not while a push is recovering.
- recovery after each push: sim time from the push's start until the base is upright (tilt under
  `UPRIGHT_TILT_RAD`) and its windowed velocity within `RECOVERED_ERROR_M_S` of the command, and stays so
  for `SETTLED_S` (before any fall); None when it never did.
- peak torque: the largest |tau| of any joint (state/joints) and which joint.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import msgspec

WINDOW_S = 0.4
"""Achieved velocity is averaged over this much sim time (half a G1 gait cycle of 0.8 s would alias)."""
UPRIGHT_TILT_RAD = 0.35
RECOVERED_ERROR_M_S = 0.25
SETTLED_S = 1.0
FALLEN_HEIGHT_M = 0.35
"""A base that sinks this far below where it started has fallen, whatever the status said in between."""


class PushResult(msgspec.Struct, frozen=True, kw_only=True):
    """One push of the run."""

    at_s: float
    """Scenario time it started acting, s."""
    force_n: tuple[float, ...]
    """World frame, N."""
    duration_s: float
    recovered_s: float | None
    """Sim time from its start until the robot was steady again, s; null: never (or it fell)."""


class EventOutcome(msgspec.Struct, frozen=True, kw_only=True):
    """One event as it was played."""

    type: str
    at_s: float
    """When the scenario asked it, s."""
    fired_s: float
    """Scenario time of the state after which it was sent, s (lockstep runs on while a query travels)."""
    ok: bool
    error: str | None = None


class ScenarioResult(msgspec.Struct, frozen=True, kw_only=True):
    """The result of one run of a scenario (`zensim scenario --result FILE.json`)."""

    name: str
    survived: bool
    completed: bool
    """The run reached end_s (false: the sim stalled, restarted or went back in time)."""
    duration_s: float
    """Scenario time covered, s."""
    distance_m: float
    tracking_error_m_s: float | None
    """RMS, over windows while a velocity was commanded; null when none was."""
    yaw_rate_error_rad_s: float | None
    pushes: tuple[PushResult, ...]
    peak_torque_nm: float
    peak_torque_joint: str
    fell_at_s: float | None = None
    events: tuple[EventOutcome, ...] = ()
    refused_events: int = 0
    note: str = ""
    """Why the run did not complete, or what else the reader must know."""
    recording: str = ""
    wall_s: float = 0.0
    """Wall time from the first state to the end, s (duration_s / wall_s: the run's real-time factor)."""


@dataclass
class Trace:
    """The run's states, as they came, in scenario time."""

    times: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)
    tilt: list[float] = field(default_factory=list)
    z: list[float] = field(default_factory=list)
    commands: list[tuple[float, tuple[float, float, float]]] = field(default_factory=list)
    """(scenario time, (vx, vy, wz)) each time the command changed."""
    fell_at_s: float | None = None
    peak_tau: float = 0.0
    peak_joint: int = -1
    fall_tilt_rad: float | None = None
    """The sim's fall threshold (RobotInfo.fall_tilt_rad): a state tilted past it is a fall, at that state's sim
    time; None: the status's `fallen` says it (at the status's time: wall-clock paced, so not the same in every
    run)."""

    def add_odometry(self, t: float, pos: Sequence[float], quat_wxyz: Sequence[float]) -> None:
        w, x, y, z = quat_wxyz
        self.times.append(t)
        self.xy.append((pos[0], pos[1]))
        self.z.append(pos[2])
        self.yaw.append(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
        # The base's z axis against the world's: cos(tilt) = 1 - 2 (x^2 + y^2).
        self.tilt.append(math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y)))))
        if self.fell_at_s is None and (self.z[0] - pos[2] > FALLEN_HEIGHT_M or (
                self.fall_tilt_rad is not None and self.tilt[-1] > self.fall_tilt_rad)):
            self.fell_at_s = t

    def add_torques(self, tau: Sequence[float]) -> None:
        for index, value in enumerate(tau):
            if abs(value) > self.peak_tau:
                self.peak_tau, self.peak_joint = abs(value), index

    def fallen(self, t: float) -> None:
        """The status said fallen at `t`: a fall unless the states judge it themselves (`fall_tilt_rad`)."""
        if self.fell_at_s is None and self.fall_tilt_rad is None:
            self.fell_at_s = t

    def command(self, t: float, velocity: tuple[float, float, float]) -> None:
        self.commands.append((t, velocity))

    def commanded_at(self, t: float) -> tuple[float, float, float] | None:
        index = bisect.bisect_right([c[0] for c in self.commands], t) - 1
        return self.commands[index][1] if index >= 0 else None


def windowed_velocity(trace: Trace, i: int, j: int) -> tuple[float, float, float]:
    """Achieved (vx, vy) in the heading frame at sample i and yaw rate, between samples i and j."""
    dt = trace.times[j] - trace.times[i]
    dx, dy = trace.xy[j][0] - trace.xy[i][0], trace.xy[j][1] - trace.xy[i][1]
    heading = trace.yaw[i]
    c, s = math.cos(heading), math.sin(heading)
    dyaw = math.remainder(trace.yaw[j] - trace.yaw[i], math.tau)
    return (c * dx + s * dy) / dt, (-s * dx + c * dy) / dt, dyaw / dt


def _windows(trace: Trace) -> list[tuple[int, int]]:
    """Consecutive sample index pairs about WINDOW_S of sim time apart."""
    pairs, i = [], 0
    for j in range(1, len(trace.times)):
        if trace.times[j] - trace.times[i] >= WINDOW_S:
            pairs.append((i, j))
            i = j
    return pairs


def _recovery(trace: Trace, start_s: float, end_s: float) -> float | None:
    """Sim time from a push's start until the robot is steady for SETTLED_S, or None."""
    steady_since: float | None = None
    n = len(trace.times)
    i = bisect.bisect_left(trace.times, end_s)
    while i < n:
        j = bisect.bisect_left(trace.times, trace.times[i] + WINDOW_S / 2, lo=i)
        if j >= n:
            break
        t = trace.times[i]
        commanded = trace.commanded_at(t) or (0.0, 0.0, 0.0)
        vx, vy, _ = windowed_velocity(trace, i, j)
        steady = (trace.tilt[i] < UPRIGHT_TILT_RAD
                  and math.hypot(vx - commanded[0], vy - commanded[1]) < RECOVERED_ERROR_M_S)
        if not steady:
            steady_since = None
        elif steady_since is None:
            steady_since = t
        elif t - steady_since >= SETTLED_S:
            return steady_since - start_s
        i = j
    return None


def score(trace: Trace, name: str, pushes: Sequence[tuple[float, tuple[float, ...], float]], joint_names: Sequence[str],
          completed: bool, events: Sequence[EventOutcome], note: str = "", recording: str = "",
          wall_s: float = 0.0) -> ScenarioResult:
    """The result of a run from its trace; `pushes` are (start, force, duration) as the sim applied them."""
    survived = trace.fell_at_s is None and completed  # a run cut short proves nothing
    distance = math.dist(trace.xy[0], trace.xy[-1]) if trace.xy else 0.0
    push_windows = [(start, start + duration + SETTLED_S) for start, _, duration in pushes]
    linear: list[float] = []
    angular: list[float] = []
    for i, j in _windows(trace):
        commanded = trace.commanded_at(trace.times[i])
        if commanded is None or any(a <= trace.times[i] < b for a, b in push_windows):
            continue
        if trace.fell_at_s is not None and trace.times[j] >= trace.fell_at_s:
            break
        vx, vy, wz = windowed_velocity(trace, i, j)
        linear.append((vx - commanded[0]) ** 2 + (vy - commanded[1]) ** 2)
        angular.append((wz - commanded[2]) ** 2)
    results = []
    for start, force, duration in pushes:
        recovered = None
        if trace.fell_at_s is None or start < trace.fell_at_s:  # a push before a fall may have been ridden out
            recovered = _recovery(trace, start, start + duration)
            if recovered is not None and trace.fell_at_s is not None and start + recovered + SETTLED_S > trace.fell_at_s:
                recovered = None
        results.append(PushResult(at_s=round(start, 4), force_n=tuple(round(f, 3) for f in force),
                                  duration_s=duration, recovered_s=None if recovered is None else round(recovered, 3)))
    joint = joint_names[trace.peak_joint] if 0 <= trace.peak_joint < len(joint_names) else ""
    return ScenarioResult(
        name=name, survived=survived, completed=completed, duration_s=round(trace.times[-1], 4) if trace.times else 0.0,
        distance_m=round(distance, 4),
        tracking_error_m_s=round(math.sqrt(sum(linear) / len(linear)), 4) if linear else None,
        yaw_rate_error_rad_s=round(math.sqrt(sum(angular) / len(angular)), 4) if angular else None,
        pushes=tuple(results), peak_torque_nm=round(trace.peak_tau, 3), peak_torque_joint=joint,
        fell_at_s=None if trace.fell_at_s is None else round(trace.fell_at_s, 4), events=tuple(events),
        refused_events=sum(not e.ok for e in events), note=note, recording=recording, wall_s=round(wall_s, 3))


def result_lines(result: ScenarioResult) -> list[str]:
    """One line per result, as `zensim scenario` prints them."""
    lines = [f"scenario {result.name}: {'completed' if result.completed else 'stopped'} at {result.duration_s:.2f} s"
             + (f" ({result.note})" if result.note else ""),
             "survived: " + ("yes" if result.survived else "no (the run did not reach its end)" if result.fell_at_s is None
                             else f"no (fell at {result.fell_at_s:.2f} s)"),
             f"distance: {result.distance_m:.2f} m",
             "tracking error: " + ("no velocity commanded" if result.tracking_error_m_s is None else
                                   f"{result.tracking_error_m_s:.3f} m/s RMS, yaw rate {result.yaw_rate_error_rad_s:.3f} rad/s")]
    for push in result.pushes:
        force = math.sqrt(sum(f * f for f in push.force_n))
        recovered = "not recovered" if push.recovered_s is None else f"recovered in {push.recovered_s:.2f} s"
        lines.append(f"push at {push.at_s:.2f} s ({force:.0f} N for {push.duration_s:.3f} s): {recovered}")
    lines.append(f"peak torque: {result.peak_torque_nm:.1f} N m ({result.peak_torque_joint or 'no joint states'})")
    for event in result.events:
        if not event.ok:
            lines.append(f"event {event.type} at {event.at_s:g} s refused: {event.error}")
    if result.wall_s > 0:
        lines.append(f"wall time: {result.wall_s:.2f} s ({result.duration_s / result.wall_s:.1f} x real time)")
    if result.recording:
        lines.append(f"recording: {result.recording}")
    return lines
