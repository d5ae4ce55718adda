"""The DDS side: a Cyclone DDS participant with Unitree's topics, as unitree_sdk2 names them.

    rt/lowcmd                            LowCmd_   read   (the controller's commands)
    rt/lowstate                          LowState_ written
    rt/api/motion_switcher/request       Request_  read
    rt/api/motion_switcher/response      Response_ written

The domain is configured as the SDK's `ChannelFactoryInitialize(domain, interface)` does it:
an XML config naming the network interface (Cyclone DDS turns multicast off on `lo` and finds
local participants by unicast). QoS is Cyclone's default on both sides, as in the SDK, except
rt/lowcmd's reader history (LOWCMD_HISTORY) and the request readers' (requests.py's REQUEST_HISTORY),
which only the readers see. On a loopback interface
the participant's sockets are tied to it (common/ddsbind.py: Cyclone binds them to 0.0.0.0), and Cyclone's
own log lines go through a rate limiter (common/ddslog.py).

LowCmd_/LowState_ travel as raw serialized bytes through the binding's C layer (`_clayer`, the
calls DataReader.take and DataWriter.write make after their own, slow, (de)serialization; see
codec.py). That layer is internal to the cyclonedds package, which is why the project pins the
binding to exactly 0.10.2 (scripts/install-cyclonedds).
"""

from __future__ import annotations

import logging
from xml.sax.saxutils import quoteattr

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from zensim.common.ddsbind import is_loopback, pin_to_device, udp_sockets
from zensim.common.ddslog import route_cyclone_log
from .idl import LowCmd_, LowState_, Request_, Response_
from .requests import REQUEST_HISTORY

LOWCMD_TOPIC = "rt/lowcmd"
LOWSTATE_TOPIC = "rt/lowstate"
LOWSTATE_LF_TOPIC = "rt/lf/lowstate"
"""The low-frequency copy of LowState_ the robot also publishes (Unitree's wireless_controller example reads it)."""
MOTION_SWITCHER_REQUEST = "rt/api/motion_switcher/request"
MOTION_SWITCHER_RESPONSE = "rt/api/motion_switcher/response"

logger = logging.getLogger("zensim.unitree")

LOWCMD_HISTORY = 32
"""LowCmd_ samples rt/lowcmd's reader keeps until they are taken (Cyclone's default keeps 1 and replaces it
unseen). The adapter applies the newest of each take and counts the rest as shed; a flood faster than
this many samples per take (32 kHz at 1 ms takes) also loses older samples in Cyclone's cache, uncounted."""


def take_serialized(reader: DataReader, max_samples: int) -> list[bytes]:
    """Up to `max_samples` samples of `reader`, serialized (header included), oldest first; none decoded."""
    result = ddspy_take(reader._ref, max_samples)
    if isinstance(result, int):
        return []
    return [data for data, info in result if info.valid_data]


def domain_config(interface: str) -> str:
    """Cyclone DDS XML for one network interface (empty: let Cyclone choose, as the SDK does)."""
    if interface:
        nic = f"<NetworkInterface name={quoteattr(interface)} priority=\"default\" multicast=\"default\"/>"
    else:
        nic = '<NetworkInterface autodetermine="true" priority="default" multicast="default"/>'
    return (
        '<?xml version="1.0" encoding="UTF-8" ?><CycloneDDS><Domain Id="any"><General><Interfaces>'
        f"{nic}</Interfaces></General></Domain></CycloneDDS>"
    )


class UnitreeDds:
    """The participant, its readers and writers, and one waitset over both readers.

    Args:
        domain_id: DDS domain (the robot uses 0, unitree_mujoco's examples 1).
        interface: network interface name (e.g. lo, eth0); empty lets Cyclone choose.
    """

    def __init__(self, domain_id: int, interface: str) -> None:
        route_cyclone_log()  # before the domain exists: its first lines already go through the limiter
        before = udp_sockets()
        # The Domain object must outlive the participant: it holds the configuration.
        self.domain = Domain(domain_id, domain_config(interface))
        self.participant = DomainParticipant(domain_id)
        self.pinned_sockets = 0
        """Cyclone's wildcard-bound sockets tied to the loopback interface (ddsbind.py)."""
        if is_loopback(interface):
            try:
                self.pinned_sockets = pin_to_device(udp_sockets() - before, interface)
            except OSError as exc:  # Linux before 5.7 without CAP_NET_RAW: works, but not confined
                logger.error("cannot tie Cyclone DDS's sockets to %s (%s): DDS takes packets from every "
                             "interface", interface, exc)
        self.lowcmd_reader = DataReader(self.participant, Topic(self.participant, LOWCMD_TOPIC, LowCmd_),
                                        qos=Qos(Policy.History.KeepLast(LOWCMD_HISTORY)))
        self.lowstate_writer = DataWriter(self.participant, Topic(self.participant, LOWSTATE_TOPIC, LowState_))
        self.lowstate_lf_writer = DataWriter(self.participant, Topic(self.participant, LOWSTATE_LF_TOPIC, LowState_))
        self.request_reader = DataReader(self.participant, Topic(self.participant, MOTION_SWITCHER_REQUEST, Request_),
                                         qos=Qos(Policy.History.KeepLast(REQUEST_HISTORY)))
        self.response_writer = DataWriter(self.participant, Topic(self.participant, MOTION_SWITCHER_RESPONSE, Response_))
        mask = SampleState.NotRead | ViewState.Any | InstanceState.Any
        self.lowcmd_ready = ReadCondition(self.lowcmd_reader, mask)
        self.request_ready = ReadCondition(self.request_reader, mask)
        self.waitset = WaitSet(self.participant)
        self.waitset.attach(self.lowcmd_ready)
        self.waitset.attach(self.request_ready)

    def wait(self, timeout_s: float) -> None:
        """Block until a reader has data or `timeout_s` passes."""
        self.waitset.wait(duration(seconds=timeout_s))

    def has_lowcmd(self) -> bool:
        return bool(self.lowcmd_ready.triggered)

    def take_lowcmd(self, max_samples: int = LOWCMD_HISTORY) -> list[bytes]:
        """Serialized LowCmd_ samples that arrived (header included), oldest first."""
        return take_serialized(self.lowcmd_reader, max_samples)

    def write_lowstate(self, data: bytes) -> None:
        """Publish one serialized LowState_ (codec.encode_low_state)."""
        ret = ddspy_write(self.lowstate_writer._ref, data)
        if ret < 0:
            raise OSError(f"dds_write on {LOWSTATE_TOPIC} failed with {ret}")

    def write_lowstate_lf(self, data: bytes) -> None:
        """Publish one serialized LowState_ on the low-frequency topic."""
        ret = ddspy_write(self.lowstate_lf_writer._ref, data)
        if ret < 0:
            raise OSError(f"dds_write on {LOWSTATE_LF_TOPIC} failed with {ret}")

    def take_requests(self) -> list[bytes]:
        """Every waiting motion-switcher request, serialized (requests.py decodes those it answers)."""
        return take_serialized(self.request_reader, REQUEST_HISTORY)

    def has_request(self) -> bool:
        return bool(self.request_ready.triggered)

    def respond(self, response: Response_) -> None:
        self.response_writer.write(response)
