"""The edges outside Zenoh's authentication: ROS 1 (master, XML-RPC and TCPROS servers) and Unitree's DDS.

Neither protocol has any authentication here: whoever reaches their ports reads everything and drives
the robot, whatever `--secure-dir` does for Zenoh. One rule for both (docs/security.md):

- loopback by default (this machine's users only);
- beyond loopback only when asked (an address or interface set by the user), with one warning;
- under `--secure-dir` not beyond loopback at all, unless the user also says `--open-edge true`: a
  secured network must not have an open door nobody chose.
"""

from __future__ import annotations

import ipaddress
import logging

from .session import StartupError

OPEN_EDGE_FLAG = "--open-edge true"
"""What a user adds to run an edge beyond loopback under --secure-dir (zensim up: --open-edges true)."""


def is_loopback(address: str) -> bool:
    """Whether a bind address or host name stays on this machine (`localhost`, 127.0.0.0/8, ::1)."""
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address.strip("[]")).is_loopback
    except ValueError:
        return False


def check_edge(edge: str, where: str, loopback: bool, secure_dir: str | None, open_edge: bool,
               logger: logging.Logger, flag: str = OPEN_EDGE_FLAG) -> None:
    """Refuse an edge beyond loopback under --secure-dir unless opened explicitly; warn once otherwise.

    Args:
        edge: what listens, for the messages (`the ROS 1 gateway`).
        where: the address or interface it listens on, for the messages.
        loopback: whether that stays on this machine.
        secure_dir: the service's --secure-dir (None: Zenoh is not secured either).
        open_edge: the user's explicit `--open-edge true`.
        logger: the service's logger, for the warning.
        flag: how the user opens it, for the refusal.

    Raises:
        StartupError: beyond loopback under --secure-dir without `open_edge`.
    """
    if loopback:
        return
    if secure_dir and not open_edge:
        raise StartupError(f"{edge} would listen on {where}, beyond loopback, but it has no authentication: "
                           f"--secure-dir secures Zenoh only. Keep it on loopback, or add {flag} to "
                           "open it anyway (docs/security.md)")
    logger.warning("%s listens on %s, beyond loopback: it has no authentication, so anyone who reaches it reads "
                   "the robot's state and drives it (docs/security.md)", edge, where)
