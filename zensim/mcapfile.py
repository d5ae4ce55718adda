"""zensim recordings as MCAP files: which key is which channel and schema, and reading them back.

One channel per key (the topic is the full key, `zensim/g1/state/joints`), JSON message encoding,
and the message's JSON Schema from schemas/jsonschema as the channel's schema (encoding
`jsonschema`), so Foxglove and the `mcap` CLI show fields by name. A message's log time is when the
recorder received it (wall clock, ns since the epoch); its publish time is its sim time where it has
one (`sim_time_s`), else the log time. `cmd/joint/{joint}` carries a bare number on the wire; in the
file it is `{"value": x}`, since JSON readers of MCAP expect objects.

The sim's description is saved with the data: attachment `info/robot` (RobotInfo as JSON),
`info/urdf` (the URDF text) and one `info/mesh/{path}` per mesh file it names, again after a sim
restart or mode switch (readers here use the first), plus a metadata record `zensim` (robot id,
format version).

No zenoh here: `zensim resim` reads files without a network.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import IO, Any, Final

import msgspec
from mcap.reader import make_reader
from mcap.writer import Writer

from zensim import __version__
from zensim.schemas import ROOT, TOPICS, Codec, Message, RobotInfo
from zensim.schemas.generate import tag_of

PROFILE: Final = "zensim"
METADATA_NAME: Final = "zensim"
FORMAT_VERSION: Final = "1"
ROBOT_INFO_ATTACHMENT: Final = "info/robot"
URDF_ATTACHMENT: Final = "info/urdf"
MESH_ATTACHMENT_PREFIX: Final = "info/mesh/"
"""Each mesh the description names is saved as attachment `info/mesh/{path}` (its path as RobotInfo.mesh_paths
names it), so a replay can serve the robot's looks too."""
SCALAR_SCHEMA: Final = {
    "title": "scalar",
    "description": "A bare number sent on cmd/joint/{joint}, wrapped as an object.",
    "type": "object",
    "properties": {"value": {"type": "number"}},
    "required": ["value"],
}



def message_type_of(relative_key: str) -> type[Message] | type[float] | None:
    """The message type of a key under `zensim/{robot}/` (float for bare numbers); None if unknown."""
    for topic in TOPICS:
        if topic.kind != "publication":
            continue
        pattern = topic.key.split("/")
        parts = relative_key.split("/")
        if len(pattern) == len(parts) and all(p == k or p.startswith("{") for p, k in zip(pattern, parts)):
            return float if topic.payload == "float" else topic.message
    return None


def non_finite_at(message: object) -> str | None:
    """Where a message holds NaN or an infinity (`q[3]`), or None: JSON cannot carry those (msgspec would
    write `null`, which the channel's schema refuses), so such a sample is not recorded."""
    return _non_finite_at(msgspec.to_builtins(message), "")


def _non_finite_at(value: Any, where: str) -> str | None:
    if isinstance(value, float):
        return None if math.isfinite(value) else (where or "the value")
    if isinstance(value, dict):
        items: Any = value.items()
    elif isinstance(value, (list, tuple)):
        items = ((f"[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for name, item in items:
        found = _non_finite_at(item, f"{where}{name}" if name.startswith("[") else f"{where}.{name}".lstrip("."))
        if found is not None:
            return found
    return None


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number")


def strict_json(data: bytes | str) -> bytes:
    """Re-encode JSON compactly, refusing NaN and Infinity (Python's json reads and writes them; strict
    readers do not). Raises ValueError (or RecursionError for absurd nesting)."""
    return json.dumps(json.loads(data, parse_constant=_refuse_constant), allow_nan=False).encode()


def split_key(key: str) -> tuple[str, str]:
    """`zensim/g1/state/joints` -> (`g1`, `state/joints`)."""
    root, robot, relative = key.split("/", 2)
    if root != ROOT:
        raise ValueError(f"{key!r} is not a zensim key")
    return robot, relative


def schema_bytes(message_type: type) -> tuple[str, bytes]:
    """(schema name, JSON Schema text) of a message type, from the generated files."""
    if message_type is float:
        return "scalar", json.dumps(SCALAR_SCHEMA).encode()
    tag = tag_of(message_type)
    text = (resources.files("zensim.schemas.jsonschema") / f"{tag}.json").read_bytes()
    return tag, text


class RecordingWriter:
    """Writes samples into an MCAP file, one channel per key, registering channels as keys appear.

    Args:
        stream: a binary file opened for writing.
        robot_id: the robot the recording is of (stored in the metadata).
    """

    def __init__(self, stream: IO[bytes], robot_id: str) -> None:
        self._writer = Writer(stream)
        self._writer.start(profile=PROFILE, library=f"zensim {__version__}")
        self._writer.add_metadata(METADATA_NAME, {"robot_id": robot_id, "format_version": FORMAT_VERSION})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0

    def _channel(self, key: str, message_type: type | None) -> int:
        channel = self._channels.get(key)
        if channel is None:
            schema_id = 0  # schemaless JSON: a key this version does not know
            if message_type is not None:
                name, text = schema_bytes(message_type)
                if name not in self._schemas:
                    self._schemas[name] = self._writer.register_schema(name, "jsonschema", text)
                schema_id = self._schemas[name]
            channel = self._writer.register_channel(key, "json", schema_id)
            self._channels[key] = channel
        return channel

    def has_channel(self, key: str) -> bool:
        return key in self._channels

    def write(self, key: str, message_type: type | None, json_data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        self._sequence += 1
        self._writer.add_message(self._channel(key, message_type), log_time=log_time_ns, data=json_data,
                                 publish_time=publish_time_ns, sequence=self._sequence)

    def attach(self, name: str, media_type: str, data: bytes, time_ns: int) -> None:
        self._writer.add_attachment(create_time=time_ns, log_time=time_ns, name=name, media_type=media_type, data=data)

    def finish(self) -> None:
        """Write the summary and index: the file is complete and seekable after this."""
        self._writer.finish()


@dataclass(frozen=True)
class Recorded:
    """One decoded message of a recording."""

    key: str
    relative_key: str
    log_time_ns: int
    message: Any
    """A wire Struct, a float (cmd/joint/{joint}) or, for an unknown key, the decoded JSON."""


@dataclass
class Recording:
    """A whole recording read back: its description and its messages in log-time order."""

    robot_id: str
    robot_info: RobotInfo | None
    urdf: str | None
    messages: list[Recorded]
    meshes: dict[str, bytes] = field(default_factory=dict)
    """Mesh files by their RobotInfo.mesh_paths name (the first description's), for the viewer of a replay."""
    unreadable: int = 0
    """Messages skipped because they do not decode as their key's type (a damaged or forged file)."""

    def of(self, relative_key: str) -> list[Any]:
        """The messages of one key (`state/joints`), in log-time order."""
        return [m.message for m in self.messages if m.relative_key == relative_key]


def read_recording(path: str | Path) -> Recording:
    """Read a zensim MCAP file.

    Raises:
        ValueError: not an MCAP file, or not one zensim wrote.
    """
    codecs: dict[type, Codec] = {}
    with open(path, "rb") as stream:
        try:
            reader = make_reader(stream)
            metadata = {m.name: m.metadata for m in reader.iter_metadata()}
            attachments: dict[str, bytes] = {}
            for attachment in reader.iter_attachments():  # the first of each: the sim as the recording began
                attachments.setdefault(attachment.name, attachment.data)
            raw = [(channel.topic, message.log_time, message.data)
                   for _schema, channel, message in reader.iter_messages(log_time_order=True)]
        except Exception as exc:  # the mcap package raises its own and struct/zstd errors for a bad file
            raise ValueError(f"{path}: not a readable MCAP file: {exc}") from None
    zensim_metadata = metadata.get(METADATA_NAME)
    if zensim_metadata is None:
        raise ValueError(f"{path}: no zensim metadata; was it written by `zensim record`?")
    robot_id = zensim_metadata.get("robot_id")
    if not robot_id:
        raise ValueError(f"{path}: the zensim metadata names no robot_id")
    try:
        info = None
        if ROBOT_INFO_ATTACHMENT in attachments:
            info = msgspec.json.decode(attachments[ROBOT_INFO_ATTACHMENT], type=RobotInfo)
        urdf = attachments[URDF_ATTACHMENT].decode() if URDF_ATTACHMENT in attachments else None
    except (msgspec.MsgspecError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise ValueError(f"{path}: its description (info/robot, info/urdf attachments) is unreadable: "
                         f"{str(exc)[:200]}") from None
    messages, unreadable = [], 0
    for topic, log_time, data in raw:
        try:
            message = _decode(topic, data, codecs)
        except (msgspec.MsgspecError, ValueError, TypeError, KeyError, RecursionError):
            unreadable += 1  # a recording is untrusted input: one bad message is skipped, not fatal
            continue
        messages.append(Recorded(topic, split_key(topic)[1], log_time, message))
    meshes = {name[len(MESH_ATTACHMENT_PREFIX):]: data for name, data in attachments.items()
              if name.startswith(MESH_ATTACHMENT_PREFIX)}
    return Recording(robot_id, info, urdf, messages, meshes, unreadable)


def _decode(topic: str, data: bytes, codecs: dict[type, Codec]) -> Any:
    """One recorded message as its key's type; raises on anything that is not."""
    _, relative = split_key(topic)
    message_type = message_type_of(relative)
    if message_type is float:
        value = json.loads(data)["value"]
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ValueError("not a finite number")
        return float(value)
    if message_type is None:
        return json.loads(data)
    codec = codecs.setdefault(message_type, Codec(message_type))
    return codec.decode(data, "application/json")

