"""What a browser may ask for, checked before anything reaches zenoh: pure logic, no zenoh.

The page speaks plain JSON. Anything else (unknown types, unknown joints,
non-finite numbers, oversized lists) is refused with a reason; slider values
are clamped to the joint limits the page shows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from zensim.schemas import JointTargets

PAGE_CTL_VERBS: Final = ("reset", "pause", "resume", "step")
MODES: Final = ("floating", "fixed")
MAX_PLOT_JOINTS: Final = 6


class PanelError(ValueError):
    """A browser message that is refused; the text is shown on the page."""


@dataclass(frozen=True)
class Ctl:
    verb: str
    """reset, pause, resume, step or mode."""
    mode: str | None = None


@dataclass(frozen=True)
class PlotRequest:
    """The joints a page wants plotted; none means plotting is off."""

    joints: tuple[str, ...]


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


def parse_client_message(data: Any, limits: JointLimits | None) -> JointTargets | Ctl | PlotRequest:
    """Turn one decoded JSON message from the page into a command.

    Args:
        data: the decoded JSON.
        limits: the current robot's joints; None before a description arrived.

    Returns:
        JointTargets for `{"type": "targets", "names": [...], "q": [...]}`,
        Ctl for `{"type": "ctl", "verb": ...}` and `{"type": "mode", "mode": ...}`,
        PlotRequest for `{"type": "plot", "joints": [...]}` (at most MAX_PLOT_JOINTS, [] stops).

    Raises:
        PanelError: anything malformed or unknown.
    """
    if not isinstance(data, dict):
        raise PanelError("message must be a JSON object")
    kind = data.get("type")
    if kind == "targets":
        if limits is None:
            raise PanelError("no robot description yet")
        names, q = data.get("names"), data.get("q")
        if not isinstance(names, list) or not isinstance(q, list) or len(names) != len(q):
            raise PanelError("targets need lists `names` and `q` of the same length")
        if not names or len(names) > len(limits.names) or len(set(map(str, names))) != len(names):
            raise PanelError("targets must name each joint at most once")
        values = []
        for name, value in zip(names, q):
            if not isinstance(name, str) or name not in limits.index:
                raise PanelError(f"unknown joint {name!r}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise PanelError(f"target of {name} must be a finite number")
            values.append(limits.clamp(name, float(value)))
        return JointTargets(names=tuple(names), q=tuple(values))
    if kind == "ctl":
        verb = data.get("verb")
        if verb not in PAGE_CTL_VERBS:
            raise PanelError(f"unknown control {verb!r}")
        return Ctl(verb=verb)
    if kind == "mode":
        mode = data.get("mode")
        if mode not in MODES:
            raise PanelError(f"mode must be one of {MODES}")
        return Ctl(verb="mode", mode=mode)
    if kind == "plot":
        joints = data.get("joints")
        if not isinstance(joints, list) or len(joints) > MAX_PLOT_JOINTS:
            raise PanelError(f"plot needs a list `joints` of at most {MAX_PLOT_JOINTS} joints")
        if joints and limits is None:
            raise PanelError("no robot description yet")
        for name in joints:
            if not isinstance(name, str) or limits is None or name not in limits.index:
                raise PanelError(f"unknown joint {name!r}")
        if len(set(joints)) != len(joints):
            raise PanelError("plot names a joint twice")
        return PlotRequest(joints=tuple(joints))
    raise PanelError(f"unknown message type {kind!r}")
