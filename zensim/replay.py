"""`zensim replay FILE [--rate R] [--robot-id ID]`: publish a recording's states again, so the viewer draws the past run.

Reads:  the MCAP file written by `zensim record`
Writes: state/joints, state/odom, state/imu, state/contacts, state/sim, state/targets, state/applied of the recording,
        at their recorded pace times 1/rate (msgpack, as the sim writes them)
Serves: info/robot, info/urdf and info/mesh/{path} from the recording (the viewer fetches the description there)
Token:  alive/sim (the viewer fetches a description when a sim appears) and alive/replay

Only states go out, never commands: a replay must not drive a live robot. It stands in for the sim
of its robot id, so it refuses to start when a live sim already serves that id.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Sequence
from typing import Annotated, ClassVar

import msgspec
import zenoh

from zensim.common.claim import current_owner, taken_message
from zensim.common.entry import fail, serve
from zensim.common.logs import setup_logging
from zensim.common.settings import CommonSettings, settings_or_exit, zero_or_at_least
from zensim.common.description import DescriptionServer, MeshError
from zensim.common.wire import Refusals, TypedPublisher
from zensim.schemas import Keys, Message, check_robot_id

from .mcapfile import Recording, read_recording

logger = logging.getLogger("zensim.replay")

PROG = "zensim replay"
REPLAYED_PREFIX = "state/"
MAX_GAP_S = 5.0
"""Longest wait between two replayed messages: a longer silence in the file (or a forged log time) is cut to this."""


class ReplaySettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim replay FILE`."""

    env_prefix: ClassVar[str] = "REPLAY"
    robot_id: str | None = None  # type: ignore[assignment]
    """Robot id to publish under; default: the recorded one."""
    file: str = ""
    """The MCAP file to replay (the first argument)."""
    rate: Annotated[float, msgspec.Meta(ge=0, le=1000)] = 1.0
    """Playback speed: 1 is the recorded pace, 2 twice as fast, 0 as fast as possible."""

    def __post_init__(self) -> None:
        zero_or_at_least(self.rate, 0.001, "rate")


def leading_file_argument(argv: Sequence[str], flag: str = "--file") -> list[str]:
    """`zensim replay FILE --rate 2` -> `--file FILE --rate 2` (the settings loader takes flags only)."""
    args = list(argv)
    if args and not args[0].startswith("-"):
        return [flag, args[0], *args[1:]]
    return args


class Replay:
    """Publishes one recording's states under one robot id and serves its description."""

    def __init__(self, session: zenoh.Session, recording: Recording, robot_id: str) -> None:
        self.session = session
        self.recording = recording
        self.keys = Keys(robot_id)
        self.info = recording.robot_info
        if self.info is not None:
            # Served under the new id: the description names the keys it is reachable on.
            self.info = msgspec.structs.replace(self.info, robot=robot_id, keys=self.keys.table())
        self.publishers: dict[str, TypedPublisher] = {}
        for item in recording.messages:
            if item.relative_key.startswith(REPLAYED_PREFIX) and item.relative_key not in self.publishers \
                    and isinstance(item.message, Message):
                key = f"{self.keys.root}/{item.relative_key}"
                self.publishers[item.relative_key] = TypedPublisher(session, key, type(item.message))
        self._meshes_by_key = {self.keys.mesh(path): data for path, data in recording.meshes.items()}
        # info/* under the sim's rules (common/description.py): a replay stands in for the sim.
        self.description = DescriptionServer(session, self.keys, Refusals(logger, "query"), lambda: self.info,
                                             lambda: recording.urdf, self._mesh, missing="the recording")
        self.tokens = [session.liveliness().declare_token(self.keys.alive(name)) for name in ("sim", "replay")]

    def _mesh(self, key: str) -> bytes:
        data = self._meshes_by_key.get(key)
        if data is None:
            raise MeshError("no such mesh in the recording (RobotInfo.mesh_paths lists them; older recordings hold none)")
        return data

    def play(self, rate: float, stop: threading.Event) -> int:
        """Publish every recorded state at its recorded pace / rate; returns how many went out."""
        items = [m for m in self.recording.messages if m.relative_key in self.publishers]
        if not items:
            return 0
        due = time.monotonic()
        previous_ns = items[0].log_time_ns
        sent, cut = 0, 0
        for item in items:
            if rate > 0:
                gap_s = (item.log_time_ns - previous_ns) / 1e9 / rate
                if gap_s > MAX_GAP_S:
                    cut += 1
                    gap_s = MAX_GAP_S
                due += max(0.0, gap_s)
                previous_ns = item.log_time_ns
                if stop.wait(max(0.0, due - time.monotonic())):
                    break
            elif stop.is_set():
                break
            self.publishers[item.relative_key].put(item.message)
            sent += 1
        if cut:
            logger.info("%d silences longer than %g s in the recording were cut to %g s", cut, MAX_GAP_S, MAX_GAP_S)
        return sent

    def close(self) -> None:
        for token in self.tokens:
            token.undeclare()
        self.description.undeclare()
        for publisher in self.publishers.values():
            publisher.undeclare()


def replay(session: zenoh.Session, settings: ReplaySettings, stop: threading.Event, recording: Recording,
           robot_id: str) -> int:
    """Publish the recording once (refused when a live sim serves `robot_id`); returns the exit code."""
    owner = current_owner(session, Keys(robot_id))
    if owner is not None:
        return fail(PROG, taken_message(robot_id, owner))
    player = Replay(session, recording, robot_id)
    logger.info("replaying %s under zensim/%s at rate %g (%d messages)", settings.file, robot_id, settings.rate,
                sum(1 for m in recording.messages if m.relative_key in player.publishers))
    if recording.unreadable:
        logger.warning("%d messages of the file did not decode as their key's type and are not replayed",
                       recording.unreadable)
    try:
        sent = player.play(settings.rate, stop)
    finally:
        player.close()
    logger.info("replay done: %d messages published", sent)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = leading_file_argument(sys.argv[1:] if argv is None else argv)
    settings = settings_or_exit(ReplaySettings, args, PROG)
    if not settings.file:
        return fail(PROG, "give the recording: zensim replay FILE [--rate R] [--robot-id ID]")
    setup_logging(settings.log_level)
    try:
        recording = read_recording(settings.file)
        robot_id = check_robot_id(settings.robot_id or recording.robot_id)
    except (OSError, ValueError) as exc:
        return fail(PROG, str(exc))
    # Secured network: the replay's own role, which stands in for a sim: it publishes state/*, serves
    # info/robot and info/urdf, and declares alive/sim and alive/replay (schemas/topics.py ROLES).
    return serve(PROG, settings, lambda session, s, stop: replay(session, s, stop, recording, robot_id), role="replay")
