"""A scenario file: a timeline of events in sim time that `zensim scenario FILE` plays against a running robot.

```toml
end_s = 12.0                       # the scenario ends this long after it starts (sim time), s

[[events]]
at_s = 0.0                         # sim time after the start, s
type = "loco"                      # a walking verb on ctl/loco: stand_up, walk, sit, damp, ...
verb = "walk"

[[events]]
at_s = 3.0
type = "velocity"                  # put on cmd/velocity, held until the next velocity event or the end
vx = 0.5

[[events]]
at_s = 6.0
type = "push"                      # ctl/push: body (default the base link), direction, force, duration
direction = [0, 1, 0]
magnitude_n = 80
duration_s = 0.2

[[events]]
at_s = 8.0
type = "band"                      # ctl/band: on, off, lower, raise, or length_m
verb = "off"

[[events]]
at_s = 9.0
type = "faults"                    # forwarded unchanged (as JSON) to the sim's ctl/faults
request = { joint = "left_knee_joint", torque_scale = 0.6 }
```

Decoded with msgspec: unknown keys, unknown event types, NaN or infinite numbers and absurd values are
refused whole, with one line naming the event and the field; nothing here touches the network. Each
event's fields are checked by the wire message it becomes (PushRequest, BandRequest, VelocityCommand,
LocoRequest), so a scenario is refused for what the service would refuse, before anything is sent.
"""

from __future__ import annotations

import math
import os
from typing import Annotated, Final

import msgspec

from zensim.schemas.messages import MAX_SCHEDULED, BandRequest, BandVerb, LocoVerb, PushRequest, VelocityCommand

MAX_EVENTS: Final = 10_000
"""Events in one scenario: hours of a busy bench at one event a second; more is a generator's mistake."""
MAX_END_S: Final = 86_400.0
"""Longest scenario, s of sim time (a day)."""
MAX_FILE_BYTES: Final = 4 * 1024 * 1024
"""Largest scenario file read (MAX_EVENTS events of a few hundred bytes each fit): a bigger file is refused
before it is parsed, so a file of a million events costs nothing."""
MAX_PUSH_N: Final = 10_000.0
"""Largest push force a scenario may ask, N; the sim refuses more than 10 x the robot's weight (3.4 kN for the G1)."""
MAX_FAULTS_REQUEST_BYTES: Final = 4096
"""Largest ctl/faults request a faults event carries, as JSON."""
MAX_FAULTS_DEPTH: Final = 8


class Event(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True, tag_field="type"):
    """What every event has: when it fires."""

    at_s: Annotated[float, msgspec.Meta(ge=0.0, le=MAX_END_S)]
    """Sim time after the scenario's start at which the event fires, s."""


class Push(Event, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="push"):
    """ctl/push: a force on a body for a while."""

    direction: tuple[float, float, float]
    """World frame, any non-zero length."""
    magnitude_n: Annotated[float, msgspec.Meta(gt=0.0, le=MAX_PUSH_N)]
    """N."""
    duration_s: float
    """Sim time, (0, 10] s."""
    body: str | None = None
    """A URDF link; default the base link (the G1's pelvis)."""

    def request(self) -> PushRequest:
        return PushRequest(direction=self.direction, magnitude_n=self.magnitude_n, duration_s=self.duration_s, body=self.body)


class Band(Event, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="band"):
    """ctl/band: the elastic band on, off, lower, raise, or a length."""

    verb: BandVerb | None = None
    length_m: float | None = None

    def request(self) -> BandRequest:
        return BandRequest(verb=self.verb, length_m=self.length_m)


class Velocity(Event, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="velocity"):
    """cmd/velocity: walk at this velocity (heading frame) until the next velocity event or the end."""

    vx: float = 0.0
    """m/s."""
    vy: float = 0.0
    """m/s, left positive."""
    wz: float = 0.0
    """rad/s, counter-clockwise positive."""

    def command(self, timeout_s: float) -> VelocityCommand:
        return VelocityCommand(vx=self.vx, vy=self.vy, wz=self.wz, timeout_s=timeout_s)


class Loco(Event, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="loco"):
    """ctl/loco: a walking verb for `zensim loco` (stand_up, walk, sit, damp, zero_torque, release)."""

    verb: LocoVerb


class Faults(Event, frozen=True, kw_only=True, forbid_unknown_fields=True, tag="faults"):
    """ctl/faults: the request is forwarded as it is written (as JSON); the sim checks it."""

    request: dict[str, object]
    """The ctl/faults request (the sim's README says its fields)."""


AnyEvent = Push | Band | Velocity | Loco | Faults
EVENT_TYPES: Final = ("push", "band", "velocity", "loco", "faults")


class Scenario(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A scenario file, checked: events sorted by time (events at one time keep the file's order)."""

    end_s: Annotated[float, msgspec.Meta(gt=0.0, le=MAX_END_S)]
    """The scenario ends this long after its start, s of sim time."""
    events: Annotated[list[AnyEvent], msgspec.Meta(max_length=MAX_EVENTS)] = []
    """The timeline."""
    name: str = ""
    """A name for the result lines and tables (default: the file's name)."""


class ScenarioError(ValueError):
    """A scenario that cannot be played: one line saying why."""


def decode_scenario(data: bytes, source: str = "the scenario") -> Scenario:
    """Decode and check a scenario's TOML text.

    Raises:
        ScenarioError: anything wrong, in one line naming the event and field.
    """
    if len(data) > MAX_FILE_BYTES:
        raise ScenarioError(f"{source}: {len(data)} bytes, more than {MAX_FILE_BYTES} (at most {MAX_EVENTS} events)")
    try:
        scenario = msgspec.toml.decode(data, type=Scenario)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise ScenarioError(f"{source}: {_unknown_type_hint(str(exc))}") from None
    except (ValueError, RecursionError, UnicodeDecodeError) as exc:  # the TOML parser's own complaints
        raise ScenarioError(f"{source}: not TOML: {str(exc)[:200]}") from None
    for index, event in enumerate(scenario.events):
        where = f"{source}: events[{index}] ({event.__struct_config__.tag} at {event.at_s:g} s)"
        if event.at_s > scenario.end_s:
            raise ScenarioError(f"{where}: after end_s {scenario.end_s:g} s")
        try:
            _check_event(event)
        except (ValueError, TypeError) as exc:
            raise ScenarioError(f"{where}: {exc}") from None
    # Sent ahead at the start (zensim/scenario.py): the sim keeps MAX_SCHEDULED requests, the walking controller
    # MAX_SCHEDULED velocities.
    for what, kinds in (("push, band and faults", (Push, Band, Faults)), ("velocity", (Velocity,))):
        count = sum(1 for event in scenario.events if isinstance(event, kinds))
        if count > MAX_SCHEDULED:
            raise ScenarioError(f"{source}: {count} {what} events, more than the {MAX_SCHEDULED} a robot keeps "
                                "waiting for their time")
    events = sorted(scenario.events, key=lambda e: e.at_s)  # stable: one instant keeps the file's order
    return msgspec.structs.replace(scenario, events=events)


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Read and check a scenario file; its name defaults to the file's stem.

    Raises:
        ScenarioError: unreadable, too big, or invalid (one line).
    """
    try:
        with open(path, "rb") as file:
            data = file.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"cannot read {os.fspath(path)}: {exc.strerror}") from None
    scenario = decode_scenario(data, os.fspath(path))
    if not scenario.name:
        scenario = msgspec.structs.replace(scenario, name=os.path.splitext(os.path.basename(path))[0])
    return scenario


def _check_event(event: AnyEvent) -> None:
    """Each event checked as the wire message it becomes (the same bounds the services apply)."""
    match event:
        case Push():
            event.request()
        case Band():
            event.request()
        case Velocity():
            event.command(1.0)
        case Faults():
            _check_finite_tree(event.request, "request", 0)
            if "at_s" in event.request:
                raise ValueError("`request.at_s` is the event's own `at_s` (the scenario sets it); leave it out")
            if len(msgspec.json.encode(event.request)) > MAX_FAULTS_REQUEST_BYTES:
                raise ValueError(f"`request` is more than {MAX_FAULTS_REQUEST_BYTES} bytes of JSON")
        case Loco():
            pass


def _check_finite_tree(value: object, path: str, depth: int) -> None:
    if depth > MAX_FAULTS_DEPTH:
        raise ValueError(f"`{path}` is nested more than {MAX_FAULTS_DEPTH} deep")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"`{path}` is {value}: not a finite number")
    if isinstance(value, dict):
        for key, item in value.items():
            _check_finite_tree(item, f"{path}.{key}", depth + 1)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _check_finite_tree(item, f"{path}[{index}]", depth + 1)
    elif not isinstance(value, (str, int, float, bool)):
        raise ValueError(f"`{path}` holds a {type(value).__name__}, which JSON cannot carry")


def _unknown_type_hint(message: str) -> str:
    """msgspec says `Invalid value 'jump' - at $.events[0].type`: name the event types that exist."""
    if "Invalid value" in message and message.endswith(".type`"):
        return f"{message}; an event's type is one of {', '.join(EVENT_TYPES)}"
    return message
