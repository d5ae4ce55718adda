"""Keep Cyclone DDS's sockets on a loopback interface when a DDS edge (the Unitree adapter, zensim ros2) is told to use one.

Cyclone DDS 0.10 binds its receive sockets (discovery and data, unicast and multicast) to 0.0.0.0
whatever interface it is configured for, and has no setting to change that (cyclonedds issue 1923:
"Why UDP multicast and unicast socket are bound to INADDR_ANY"). `--interface lo` then still took
RTPS packets from the whole network on ports 7400 + 250 * domain + 10/11. So once the participant's
sockets exist, each one bound to the wildcard address is tied to the loopback device
(SO_BINDTODEVICE; allowed without privileges since Linux 5.7): the kernel then delivers it only
packets that arrived over loopback, i.e. from this machine. `ss -lunp` shows them as `0.0.0.0%lo`.

Only loopback interfaces are pinned: on this machine, traffic to a physical interface's own address
also travels over loopback, so pinning a socket to eth0 would cut a controller on the same machine off.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

IFF_LOOPBACK = 0x8


def is_loopback(interface: str) -> bool:
    """Whether `interface` names a loopback network interface of this machine (Linux's flags)."""
    if not interface or "/" in interface or interface in (".", ".."):
        return False
    try:
        flags = int((Path("/sys/class/net") / interface / "flags").read_text(), 16)
    except (OSError, ValueError):
        return False
    return bool(flags & IFF_LOOPBACK)


def _socket_inodes() -> dict[str, int]:
    """This process's sockets: inode -> one file descriptor of it (duplicates share the inode)."""
    found: dict[str, int] = {}
    for name in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{name}")
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:"):
            found.setdefault(target, int(name))
    return found


def _udp(fd: int) -> socket.socket | None:
    """A duplicate of `fd` as a socket object (the caller closes it) if it is a UDP socket."""
    try:
        sock = socket.socket(fileno=os.dup(fd))
    except OSError:  # closed meanwhile, or a family Python does not know
        return None
    if sock.family in (socket.AF_INET, socket.AF_INET6) and sock.type == socket.SOCK_DGRAM:
        return sock
    sock.close()
    return None


def udp_sockets() -> set[str]:
    """This process's UDP sockets (their inodes)."""
    found = set()
    for inode, fd in _socket_inodes().items():
        sock = _udp(fd)
        if sock is not None:
            sock.close()
            found.add(inode)
    return found


def pin_to_device(inodes: set[str], interface: str, every_address: bool = False) -> int:
    """Tie every UDP socket in `inodes` that is bound to the wildcard address to `interface`.

    With `every_address`, sockets bound to one of this machine's other addresses are tied too (a DDS
    side that lists the host's interfaces beside `lo` only to accept local peers' locators on them:
    zensim ros2); the traffic of local processes to those addresses travels over loopback anyway.

    Returns:
        How many sockets were pinned.

    Raises:
        OSError: the kernel refused (before Linux 5.7 this needs CAP_NET_RAW).
    """
    pinned = 0
    for inode, fd in _socket_inodes().items():
        if inode not in inodes:
            continue
        sock = _udp(fd)
        if sock is None:
            continue
        with sock:
            address = sock.getsockname()[0]
            if address in ("0.0.0.0", "::") or (every_address and not address.startswith(("127.", "::1"))):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, interface.encode())
                pinned += 1
    return pinned
