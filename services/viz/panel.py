"""What a browser may ask for, checked before anything reaches zenoh: pure logic, no zenoh.

The page speaks plain JSON: one of the tagged structs below, told apart by
`type` (a msgspec tagged union: the shapes and types are checked by msgspec,
in one place). What needs the robot (joint names, limits) is checked here
after. Anything else is refused with a reason shown on the page; slider
values are clamped to the joint limits the page shows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Literal

import msgspec

from zensim.schemas import JointTargets, Mode, PushRequest, RemoteState, VelocityCommand, bounded, short_repr
from zensim.schemas.messages import BandVerb, RemoteButton

from .drive import PAGE_TIMEOUT_S, Drive

MAX_PLOT_JOINTS: Final = 6
PUSH_DIRECTIONS: Final = {"forward": (1.0, 0.0, 0.0), "back": (-1.0, 0.0, 0.0), "left": (0.0, 1.0, 0.0),
                          "right": (0.0, -1.0, 0.0)}
"""The Push button's directions, in the robot's heading frame (x forward, y left; the service turns them
into the world frame by the robot's yaw when it pushes)."""
PUSH_MAGNITUDE_N: Final = 80.0
"""The Push button's default force: a shove a standing G1 (35 kg) feels and a walking policy should catch."""
PUSH_DURATION_S: Final = 0.2


class PanelError(ValueError):
    """A browser message that is refused; the text is shown on the page."""


class PageTargets(msgspec.Struct, tag="targets", forbid_unknown_fields=True):
    """Slider moves: `{"type": "targets", "names": [...], "q": [...]}`."""

    names: list[str]
    q: list[float]


class PageCtl(msgspec.Struct, tag="ctl", forbid_unknown_fields=True):
    """A button: `{"type": "ctl", "verb": "pause"}`."""

    verb: Literal["reset", "pause", "resume", "step"]


class PageMode(msgspec.Struct, tag="mode", forbid_unknown_fields=True):
    """The mode selector: `{"type": "mode", "mode": "fixed"}`."""

    mode: Mode


class PagePlot(msgspec.Struct, tag="plot", forbid_unknown_fields=True):
    """The joints to plot: `{"type": "plot", "joints": [...]}`; [] stops plotting."""

    joints: list[str]


class PageSelect(msgspec.Struct, tag="select", forbid_unknown_fields=True):
    """The robot the panel acts on, in a world's viewer: `{"type": "select", "robot": "g1b"}`."""

    robot: str


class PageDrive(msgspec.Struct, tag="drive", forbid_unknown_fields=True):
    """Keys or gamepad: `{"type": "drive", "vx": 0.5, "vy": 0, "wz": 0, "buttons": [], "lx": 0, "ly": 1, ...}`:
    the velocity to walk at (m/s, m/s, rad/s; cmd/velocity) and the remote as held (cmd/remote)."""

    vx: float
    vy: float
    wz: float
    buttons: list[RemoteButton] = []
    lx: float = 0.0
    ly: float = 0.0
    rx: float = 0.0
    ry: float = 0.0


class PageLoco(msgspec.Struct, tag="loco", forbid_unknown_fields=True):
    """A walking verb (the Stand/Damp buttons, a gamepad's A/B): `{"type": "loco", "verb": "walk"}`."""

    verb: Literal["walk", "damp", "sit", "stand_up"]


class PageBand(msgspec.Struct, tag="band", forbid_unknown_fields=True):
    """The band buttons: `{"type": "band", "verb": "lower"}` (ctl/band)."""

    verb: BandVerb


class PagePush(msgspec.Struct, tag="push", forbid_unknown_fields=True):
    """The Push button: `{"type": "push", "direction": "forward"}` (ctl/push on the base link); the force and
    its duration may be given, within the schema's bounds (the sim bounds the force by the robot's weight)."""

    direction: Literal["forward", "back", "left", "right"]
    magnitude_n: float = PUSH_MAGNITUDE_N
    duration_s: float = PUSH_DURATION_S


PageMessage = PageTargets | PageCtl | PageMode | PagePlot | PageSelect | PageDrive | PageLoco | PageBand | PagePush
DRIVING: Final = (PageTargets, PageCtl, PageMode, PageDrive, PageLoco, PageBand, PagePush)
"""What moves the robot or the sim: refused from a page that may only watch (a viewer's token)."""


@dataclass(frozen=True)
class Ctl:
    verb: str
    """reset, pause, resume, step or mode."""
    mode: str | None = None


@dataclass(frozen=True)
class PlotRequest:
    """The joints a page wants plotted; none means plotting is off."""

    joints: tuple[str, ...]


@dataclass(frozen=True)
class Loco:
    """A walking verb for the page's robot (ctl/loco)."""

    verb: str


@dataclass(frozen=True)
class Band:
    """A band verb for the page's robot (ctl/band)."""

    verb: str


@dataclass(frozen=True)
class Push:
    """A push of the page's robot's base (ctl/push); its direction in the robot's heading frame."""

    request: PushRequest
    """What to send, its `direction` still in the heading frame (x forward, y left)."""

    @property
    def verb(self) -> str:
        return "push"


@dataclass(frozen=True)
class Select:
    """The page's robot: its sliders, buttons, status and plots are this robot's from now on."""

    robot: str


class JointLimits:
    """Joint names and limits the sliders cover."""

    def __init__(self, names: Sequence[str], lower: Sequence[float], upper: Sequence[float]) -> None:
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.lower = tuple(lower)
        self.upper = tuple(upper)

    def clamp(self, name: str, value: float) -> float:
        i = self.index[name]
        return min(max(value, self.lower[i]), self.upper[i])

    def check(self, names: Sequence[str]) -> None:
        """Refuse unknown or repeated joints."""
        for name in names:
            if name not in self.index:
                raise PanelError(f"unknown joint {short_repr(name)}")
        if len(set(names)) != len(names):
            raise PanelError("a joint is named twice")


Command = JointTargets | Ctl | PlotRequest | Select | Drive | Loco | Band | Push


def parse_client_message(data: Any, limits: JointLimits | None, may_drive: bool = True) -> Command:
    """Turn one decoded JSON message from the page into a command.

    Args:
        data: the decoded JSON.
        limits: the current robot's joints; None before a description arrived.
        may_drive: False for a page that may only watch (opened with the viewer's token).

    Returns:
        JointTargets for `targets`, Ctl for `ctl` and `mode`, PlotRequest for `plot`, Select for `select`
        (the service checks that it names a robot it shows), Drive for `drive`, Loco for `loco`, Band for
        `band`, Push for `push`.

    Raises:
        PanelError: anything malformed, unknown or out of place, or driving from a page that may only watch.
    """
    try:
        message = msgspec.convert(data, PageMessage)
    except msgspec.ValidationError as exc:
        raise PanelError(bounded(f"refused: {exc}")) from None
    if not may_drive and isinstance(message, DRIVING):
        raise PanelError(f"refused {type(message).__struct_config__.tag}: this page may watch, not drive "
                         "(it was opened with the viewer's token)")
    match message:
        case PageTargets(names=names, q=q):
            if limits is None:
                raise PanelError("no robot description yet")
            if not names:
                raise PanelError("targets name no joint")
            try:  # shape and finiteness: the schema's own checks, once
                targets = JointTargets(names=tuple(names), q=tuple(q))
            except ValueError as exc:
                raise PanelError(bounded(f"refused: {exc}")) from None
            limits.check(targets.names)
            return JointTargets(names=targets.names, q=tuple(limits.clamp(n, v) for n, v in zip(names, q)))
        case PageCtl(verb=verb):
            return Ctl(verb=verb)
        case PageMode(mode=mode):
            return Ctl(verb="mode", mode=mode)
        case PagePlot(joints=joints):
            if len(joints) > MAX_PLOT_JOINTS:
                raise PanelError(f"plot at most {MAX_PLOT_JOINTS} joints")
            if joints:
                if limits is None:
                    raise PanelError("no robot description yet")
                limits.check(joints)
            return PlotRequest(joints=tuple(joints))
        case PageSelect(robot=robot):
            return Select(robot=robot)
        case PageDrive():
            try:  # finite, not absurd (|v| <= 10), no button twice, sticks in -1..1: the schemas' own checks
                return Drive(
                    velocity=VelocityCommand(vx=message.vx, vy=message.vy, wz=message.wz, timeout_s=PAGE_TIMEOUT_S),
                    remote=msgspec.convert({"buttons": message.buttons, "lx": message.lx, "ly": message.ly,
                                            "rx": message.rx, "ry": message.ry}, RemoteState))
            except (ValueError, msgspec.ValidationError) as exc:
                raise PanelError(bounded(f"refused drive: {exc}")) from None
        case PageLoco(verb=verb):
            return Loco(verb=verb)
        case PageBand(verb=verb):
            return Band(verb=verb)
        case PagePush(direction=direction, magnitude_n=magnitude_n, duration_s=duration_s):
            try:  # finite, > 0, at most 10 s: the schema's own checks
                return Push(PushRequest(direction=PUSH_DIRECTIONS[direction], magnitude_n=magnitude_n,
                                        duration_s=duration_s))
            except ValueError as exc:
                raise PanelError(bounded(f"refused push: {exc}")) from None
    raise PanelError("unknown message")  # unreachable: the union is closed
