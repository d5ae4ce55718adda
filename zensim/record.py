"""`zensim record -o FILE.mcap`: every sample under `zensim/{robot}/**` into an MCAP file.

Reads:  zensim/{robot}/** (every publication: states, commands, reports), info/robot, info/urdf and info/mesh/{path} (gets)
Writes: the file (see zensim/mcapfile.py for the layout); nothing on the network

Zenoh's callback only stamps the receive time and queues the raw bytes; the main thread decodes,
re-encodes as JSON and writes, so a slow disk never pushes back on the network. The description
(RobotInfo, URDF) is fetched on a helper thread until the sim answers, and saved as attachments.
Ctrl-C or SIGTERM (or `--duration-s`, or `--max-bytes` of JSON written) ends the recording with a
complete, indexed file. A sample that does not decode as its key's message, or that holds a number
JSON cannot spell (NaN, Infinity: strict readers such as Foxglove refuse the file), is not written:
it is counted and logged (rate-limited). Keys are client-chosen, so channels are bounded in count
and key length: a flood of invented keys cannot grow the file's index without bound. The protocol's
own keys (those of the topic table, and `cmd/joint/{joint}` for the robot's joints) always get their
channel: invented keys share a budget of their own (MAX_OTHER_CHANNELS), so junk put before a
controller starts can never crowd its channels out of the recording.
"""

from __future__ import annotations

import json
import logging
import queue
import sys
import threading
import time
from collections.abc import Sequence
from typing import IO, Annotated, ClassVar, Final

import msgspec
import zenoh

from zensim.common.entry import fail, serve
from zensim.common.logs import RateLimitedLog, setup_logging
from zensim.common.robot_info import description_bytes
from zensim.common.settings import CommonSettings, settings_or_exit
from zensim.common.wire import payload_of
from zensim.schemas import Codec, DecodeError, Keys, RobotInfo, SimStatus, decode_scalar, topics
from zensim.schemas.topics import TOPICS
from zensim.schemas.bounds import STATE_CAP_BYTES

from .mcapfile import (MESH_ATTACHMENT_PREFIX, ROBOT_INFO_ATTACHMENT, URDF_ATTACHMENT, RecordingWriter, message_type_of, non_finite_at,
                       split_key, strict_json)

logger = logging.getLogger("zensim.record")

PROG = "zensim record"
MAX_SAMPLE_BYTES = STATE_CAP_BYTES
"""Larger samples are not recorded (counted): no zensim publication comes near this."""
MAX_OTHER_CHANNELS = 200
"""Distinct keys outside the protocol recorded (invented keys, and `cmd/joint/{joint}` for a joint the robot
lacks or before its description came); samples on more are not recorded (counted). The protocol's own keys
(~20, and one per joint) are never counted against it."""
PROTOCOL_KEYS: Final = frozenset(t.key for t in TOPICS if t.kind == "publication" and "{" not in t.key)
"""The protocol's publications with a fixed key (under `zensim/{robot}/`): each always gets its channel."""
JOINT_KEY_PREFIX: Final = topics.JOINT_TARGET.key.split("{", 1)[0]
"""`cmd/joint/`: the one publication with a placeholder; its keys are the protocol's for the robot's joints."""
MAX_MESH_BYTES = 256 * 1024 * 1024
"""All the meshes of one description saved with it, together (the G1's shells: 2.8 MB; Unitree's full: 19 MB)."""
MAX_KEY_CHARS = 256
"""Longest key recorded: a key is a channel name, written into every chunk index."""
MAX_QUEUED = 20_000
"""Samples waiting for the writer; past this the newest are dropped and counted, memory stays bounded."""
INFO_RETRY_S = 1.0
PROGRESS_PERIOD_S = 0.5


class RecordSettings(CommonSettings, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings of `zensim record`."""

    env_prefix: ClassVar[str] = "RECORD"
    output: str = "zensim.mcap"
    """MCAP file to write (-o)."""
    duration_s: Annotated[float, msgspec.Meta(ge=0, le=1e7)] = 0.0
    """Stop after this many wall seconds; 0 records until Ctrl-C or SIGTERM."""
    max_bytes: Annotated[int, msgspec.Meta(ge=0, le=2**50)] = 2 * 1024**3
    """Stop (with a complete file and a message saying so) once this much JSON is written; 0: no bound."""


class Recorder:
    """Receives samples on zenoh threads and writes them on the caller's thread."""

    def __init__(self, session: zenoh.Session, settings: RecordSettings, writer: RecordingWriter) -> None:
        self.session = session
        self.settings = settings
        self.keys = Keys(settings.robot_id)
        self.writer = writer
        self.samples: queue.Queue[tuple[str, bytes, str | None, int]] = queue.Queue(MAX_QUEUED)
        self.attachments: queue.Queue[tuple[str, str, bytes]] = queue.Queue()
        self.written = 0
        self.bytes_written = 0
        # Two counters, one writer each (the zenoh callback thread, the writing thread): a `+=` shared
        # by two threads can lose counts (docs/architecture.md, "Threads").
        self.dropped_behind = 0
        """Samples dropped because the writer was behind (zenoh's callback thread only)."""
        self.undecodable = 0
        """Samples that did not decode as their key's message (the writing thread only)."""
        self.bad_input = RateLimitedLog(logger)
        self._codecs: dict[type, Codec] = {}
        self._description_wanted = threading.Event()
        self._description_wanted.set()
        self._described: tuple[str, str] | None = None
        self._joint_names: frozenset[str] = frozenset()
        """The described robot's joints (replaced whole by the helper thread)."""
        self.other_channels = 0
        """Channels of keys outside the protocol (the writing thread only)."""
        self._subscriber = session.declare_subscriber(self.keys.everything, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        received_ns = time.time_ns()
        data, encoding = payload_of(sample)
        try:
            self.samples.put_nowait((str(sample.key_expr), data, encoding, received_ns))
        except queue.Full:
            self.dropped_behind += 1
            self.bad_input.warning("the writer is behind by %d samples: dropping", MAX_QUEUED)

    @property
    def skipped(self) -> int:
        """Samples not recorded, for whatever reason."""
        return self.dropped_behind + self.undecodable

    def fetch_description(self, stop: threading.Event) -> None:
        """Helper thread: get info/robot and info/urdf when the sim answers, and again after it restarted or
        switched mode (SimStatus says so), and hand them to the writer. Readers use the first pair."""
        while not stop.is_set():
            if not self._description_wanted.wait(0.2):
                continue
            try:
                info = self._get(self.keys.robot_info + "?format=json")
                described = msgspec.json.decode(info, type=RobotInfo)  # only a valid description is saved
                urdf = self._get(self.keys.urdf)
                meshes = self._meshes(described.mesh_paths)
            except (LookupError, ValueError, zenoh.ZError, msgspec.DecodeError, msgspec.ValidationError) as exc:
                logger.debug("no description yet: %s", exc)
                stop.wait(INFO_RETRY_S)
                continue
            self._description_wanted.clear()
            self._described = (described.run_id, described.mode)
            self._joint_names = frozenset(described.joint_names)
            self.attachments.put((ROBOT_INFO_ATTACHMENT, "application/json", info))
            self.attachments.put((URDF_ATTACHMENT, "application/xml", urdf))
            for path, data in meshes:
                self.attachments.put((MESH_ATTACHMENT_PREFIX + path, "application/octet-stream", data))
            logger.info("saved the sim's description (info/robot, info/urdf; run %s, mode %s)", *self._described)

    def _watch_sim(self, status: SimStatus) -> None:
        """A restarted sim (new run_id) or a mode switch: describe it again."""
        if self._described is not None and (status.run_id, status.mode) != self._described:
            self._description_wanted.set()

    def _meshes(self, paths: Sequence[str]) -> list[tuple[str, bytes]]:
        """The description's mesh files (a replay serves them to its viewer), at most MAX_MESH_BYTES together."""
        meshes, total = [], 0
        for path in paths:
            data = self._get(self.keys.mesh(path))
            total += len(data)
            if total > MAX_MESH_BYTES:
                raise ValueError(f"the meshes come to more than {MAX_MESH_BYTES} bytes: not saved")
            meshes.append((path, data))
        return meshes

    def _get(self, key: str) -> bytes:
        return description_bytes(self.session, key, 2.0)

    def drain(self, timeout_s: float) -> None:
        """Write what has arrived, waiting up to `timeout_s` for the first sample."""
        while True:
            try:
                name, media_type, data = self.attachments.get_nowait()
                self.writer.attach(name, media_type, data, time.time_ns())
            except queue.Empty:
                break
        try:
            item = self.samples.get(timeout=timeout_s)
        except queue.Empty:
            return
        while True:
            self._write(*item)
            if self.full():
                return  # the rest stay unwritten: the file ends at its bound, not a backlog later
            try:
                item = self.samples.get_nowait()
            except queue.Empty:
                return

    def full(self) -> bool:
        """Whether `--max-bytes` of JSON have been written."""
        return bool(self.settings.max_bytes) and self.bytes_written >= self.settings.max_bytes

    def _write(self, key: str, data: bytes, encoding: str | None, received_ns: int) -> None:
        try:
            if len(data) > MAX_SAMPLE_BYTES:
                raise DecodeError(f"{len(data)} bytes, more than {MAX_SAMPLE_BYTES}")
            new_other = False
            if not self.writer.has_channel(key):
                if len(key) > MAX_KEY_CHARS:
                    raise DecodeError(f"a key of {len(key)} characters, more than {MAX_KEY_CHARS}")
                new_other = not self._is_protocol_key(split_key(key)[1])
                if new_other and self.other_channels >= MAX_OTHER_CHANNELS:
                    raise DecodeError(f"already {MAX_OTHER_CHANNELS} keys outside the protocol recorded")
            _, relative = split_key(key)
            message_type = message_type_of(relative)
            publish_ns = received_ns
            if message_type is float:
                json_data = json.dumps({"value": decode_scalar(data, encoding)}).encode()
            elif message_type is None:
                json_data = strict_json(data)  # unknown key: kept only if it is JSON with finite numbers
            else:
                codec = self._codecs.setdefault(message_type, Codec(message_type))
                message = codec.decode(data, encoding)
                where = non_finite_at(message)
                if where is not None:
                    raise DecodeError(f"{where} is not a finite number (JSON has no NaN or Infinity)")
                json_data = codec.encode(message, "json")
                if isinstance(message, SimStatus):
                    self._watch_sim(message)
                sim_time_s = getattr(message, "sim_time_s", None)
                if isinstance(sim_time_s, float) and 0 <= sim_time_s < 1e9:
                    publish_ns = round(sim_time_s * 1e9)
        except (DecodeError, ValueError, UnicodeDecodeError, RecursionError) as exc:
            self.undecodable += 1
            self.bad_input.warning("not recorded: a sample on %s: %s", key, str(exc)[:200])
            return
        self.writer.write(key, message_type, json_data, received_ns, publish_ns)
        self.other_channels += new_other
        self.written += 1
        self.bytes_written += len(json_data)

    def _is_protocol_key(self, relative: str) -> bool:
        """A key of the protocol's table, or `cmd/joint/{joint}` for one of the described robot's joints."""
        if relative in PROTOCOL_KEYS:
            return True
        return relative.startswith(JOINT_KEY_PREFIX) and relative[len(JOINT_KEY_PREFIX):] in self._joint_names

    def close(self) -> None:
        self._subscriber.undeclare()


def record(session: zenoh.Session, settings: RecordSettings, stop: threading.Event, stream: IO[bytes]) -> int:
    """Record until `stop` (SIGINT/SIGTERM) or `duration_s`; the file is finished whatever ends it."""
    progress = sys.stderr.isatty()
    writer = RecordingWriter(stream, settings.robot_id)
    recorder = Recorder(session, settings, writer)
    fetcher = threading.Thread(target=recorder.fetch_description, args=(stop,), name="record-info", daemon=True)
    fetcher.start()
    started = time.monotonic()
    next_progress = started
    logger.info("recording zensim/%s/** into %s", settings.robot_id, settings.output)
    try:
        while not stop.is_set():
            recorder.drain(0.05)
            now = time.monotonic()
            if settings.duration_s and now - started >= settings.duration_s:
                break
            if recorder.full():
                logger.warning("stopped at --max-bytes %d: %.2f MB of JSON written; start another recording to go on",
                               settings.max_bytes, recorder.bytes_written / 1e6)
                break
            if progress and now >= next_progress:
                next_progress = now + PROGRESS_PERIOD_S
                sys.stderr.write(f"\rrecording {settings.output}: {now - started:7.1f} s  "
                                 f"{recorder.written} messages  {recorder.bytes_written / 1e6:.2f} MB  ")
                sys.stderr.flush()
    finally:
        recorder.close()
        stop.set()
        recorder.drain(0.0)
        writer.finish()
        if progress:
            sys.stderr.write("\n")
    logger.info("wrote %s: %d messages (%.2f MB of JSON) in %.1f s; %d samples not recorded",
                settings.output, recorder.written, recorder.bytes_written / 1e6, time.monotonic() - started,
                recorder.skipped)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = ["--output" if a == "-o" else a for a in (sys.argv[1:] if argv is None else argv)]
    settings = settings_or_exit(RecordSettings, args, PROG)
    setup_logging(settings.log_level)
    try:
        stream = open(settings.output, "wb")
    except OSError as exc:
        return fail(PROG, f"cannot write {settings.output}: {exc.strerror}")
    with stream:
        # Secured network: the recorder's own role (subscribe everything, query info/robot and info/urdf).
        return serve(PROG, settings, lambda session, s, stop: record(session, s, stop, stream), role="recorder")
