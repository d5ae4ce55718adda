"""ROS 2 on DDS: the topics as ROS 2's default middleware names them, through Cyclone DDS.

A ROS 2 topic `/joint_states` of type sensor_msgs/msg/JointState is the DDS topic `rt/joint_states`
of type `sensor_msgs::msg::dds_::JointState_`, its samples plain little-endian CDR: what rmw_fastrtps
and rmw_cyclonedds both use, so nodes on Fast DDS (ROS 2's default) or Cyclone DDS see the robot with
no configuration beyond the domain id.

Samples travel as raw CDR bytes through the binding's C layer (the bytes messages.py builds, the same
the Zenoh side sends; received bytes go to the gateway undecoded). The types are declared by name only:
Cyclone DDS would announce an XTypes type object built from a Python class, whose identifier differs
from the one Fast DDS announces for the same message, and then matches nothing; with no type object,
endpoints match on the type name, as between ROS 2 middlewares. (The binding reads `_xt_bytedata` of the
type when the topic is made; None there means "no type information".)

On a loopback interface (`lo`, the default), discovery is by unicast to this machine's well-known ports
(loopback has no multicast), the host's other addresses are listed too because Fast DDS announces its
locators on them (Cyclone drops a participant whose addresses are on none of its interfaces), and every
socket, those bound to the other interfaces' addresses included, is then tied to `lo` (common/ddsbind.py):
only processes of this machine are heard.
"""

# No `from __future__ import annotations` here: Cyclone DDS reads the type class's annotations at run time.
import logging
import socket
import threading
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import InstanceState, Policy, Qos as DdsQos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as idl
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from zensim.common.ddsbind import is_loopback, pin_to_device, udp_sockets
from zensim.common.ddslog import route_cyclone_log

from .messages import RosType
from .rmw_zenoh import Qos
from .transport import OnBad, OnMessage

logger = logging.getLogger("zensim.ros2")

TAKE_BATCH = 32
"""Samples taken from one reader per wake-up; a flood beyond it waits for the next turn (or is dropped by
the reader's history, which keeps the newest READER_DEPTH)."""
READER_DEPTH = 10
"""Samples a command reader keeps until taken (ROS 2's default depth)."""
WAIT_S = 0.1
"""Longest the reader thread sleeps between looks at the stop flag, s."""


def dds_topic(topic: str) -> str:
    """The DDS topic of a ROS 2 topic: `/joint_states` -> `rt/joint_states`."""
    return "rt/" + topic.strip("/")


def _host_interfaces() -> list[str]:
    """This machine's network interfaces that are up, loopback excepted."""
    names = []
    for _, name in socket.if_nameindex():
        try:
            state = (Path("/sys/class/net") / name / "operstate").read_text().strip()
        except OSError:
            continue
        if state != "down" and not is_loopback(name):
            names.append(name)
    return names


def domain_config(interface: str) -> str:
    """Cyclone DDS XML for the DDS side (see the module docstring)."""
    if not is_loopback(interface):
        nic = f'<NetworkInterface name={quoteattr(interface)} priority="default" multicast="default"/>'
        return ('<?xml version="1.0" encoding="UTF-8" ?><CycloneDDS><Domain Id="any"><General><Interfaces>'
                f"{nic}</Interfaces></General></Domain></CycloneDDS>")
    nics = "".join(f'<NetworkInterface name={quoteattr(name)} multicast="false"/>'
                   for name in [interface, *_host_interfaces()])
    return ('<?xml version="1.0" encoding="UTF-8" ?><CycloneDDS><Domain Id="any"><General><Interfaces>'
            f"{nics}</Interfaces></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
            '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
            "</Discovery></Domain></CycloneDDS>")


_TYPES: dict[str, type[IdlStruct]] = {}


def _named_type(ros_type: RosType) -> type[IdlStruct]:
    """A DDS type that carries `ros_type`'s name and no type object (the fields are never used: samples
    are raw bytes)."""
    name = ros_type.dds_name
    if name not in _TYPES:
        @dataclass
        class Named(IdlStruct, typename=name):  # type: ignore[call-arg]  # cyclonedds: untyped
            data: idl.sequence[idl.uint8]

        Named.__idl__.fill_type_data()
        Named.__idl__._xt_bytedata = (None, None)  # no XTypes type object: match on the name (docstring)
        _TYPES[name] = Named
    return _TYPES[name]


def _writer_qos(qos: Qos) -> DdsQos:
    durability = Policy.Durability.TransientLocal if qos.transient_local else Policy.Durability.Volatile
    return DdsQos(Policy.Reliability.Reliable(duration(seconds=1)), durability, Policy.History.KeepLast(qos.depth))


class DdsWriter:
    def __init__(self, writer: DataWriter, topic: str) -> None:
        self._writer = writer
        self._topic = topic

    def put(self, payload: bytes) -> None:
        if ddspy_write(self._writer._ref, payload) < 0:
            raise OSError(f"dds_write on {self._topic} failed")


class DdsEdge:
    """One participant; its readers are served by one thread.

    Args:
        domain: the ROS domain id (the DDS domain).
        interface: the network interface (`lo`: this machine only).
        cap_bytes: the largest sample a reader accepts.
    """

    name = "dds"

    def __init__(self, domain: int, interface: str, cap_bytes: int) -> None:
        route_cyclone_log()
        before = udp_sockets()
        self._domain = Domain(domain, domain_config(interface))  # must outlive the participant
        self._participant = DomainParticipant(domain)
        if is_loopback(interface):
            try:
                pin_to_device(udp_sockets() - before, interface, every_address=True)
            except OSError as exc:
                logger.error("cannot tie Cyclone DDS's sockets to %s (%s): DDS takes packets from every "
                             "interface", interface, exc)
        self._cap_bytes = cap_bytes
        self._topics: dict[str, Topic] = {}
        self._readers: list[tuple[DataReader, ReadCondition, str, OnMessage, OnBad]] = []
        self._waitset = WaitSet(self._participant)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _topic(self, topic: str, ros_type: RosType) -> Topic:
        name = dds_topic(topic)
        if name not in self._topics:
            self._topics[name] = Topic(self._participant, name, _named_type(ros_type))
        return self._topics[name]

    def publisher(self, topic: str, ros_type: RosType, qos: Qos) -> DdsWriter:
        return DdsWriter(DataWriter(self._participant, self._topic(topic, ros_type), qos=_writer_qos(qos)), topic)

    def subscribe(self, topic: str, ros_type: RosType, on_message: OnMessage, on_bad: OnBad) -> None:
        # Best effort accepts reliable and best-effort publishers alike (a reliable reader would not see a
        # publisher with ROS 2's sensor-data QoS).
        qos = DdsQos(Policy.Reliability.BestEffort, Policy.History.KeepLast(READER_DEPTH))
        reader = DataReader(self._participant, self._topic(topic, ros_type), qos=qos)
        ready = ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)
        self._waitset.attach(ready)
        self._readers.append((reader, ready, topic, on_message, on_bad))
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name="ros2-dds", daemon=True)
            self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            self._waitset.wait(duration(seconds=WAIT_S))
            for reader, ready, topic, on_message, on_bad in list(self._readers):
                if not ready.triggered:
                    continue
                result = ddspy_take(reader._ref, TAKE_BATCH)
                if isinstance(result, int):
                    continue
                for data, info in result:
                    if not info.valid_data:
                        continue
                    if len(data) > self._cap_bytes:
                        on_bad(f"{len(data)} bytes on {topic} (at most {self._cap_bytes})")
                        continue
                    on_message(bytes(data))

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * WAIT_S + 1)
