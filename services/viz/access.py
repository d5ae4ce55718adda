"""Who may open the viewer page: a Host allow-list against DNS rebinding, and an access token when the
page is reachable beyond loopback. Pure logic, no tornado: web.py asks `Guard` about each request.

DNS rebinding: a page from `attacker.example` whose name re-resolves to 127.0.0.1 is same-origin with
itself, so an Origin check alone lets it open our websocket. Its requests still carry
`Host: attacker.example`, so only Host names we expect are served: loopback names, the address we
serve on, names the user lists, and IP literals (a rebinding page always uses a DNS name).

Token: when the page is reachable beyond loopback (bound to another address, or published there by
Docker, `published_on`), or the network is secured (`--secure-dir`: then any local process could
otherwise drive the robot through the page with none of the network's credentials), every request
needs the token, given once as `?token=...` (the URL printed at start, like Jupyter) and then kept in
an HttpOnly, SameSite=Strict cookie.

Roles: the token makes a page an operator's (it drives: sliders, buttons, keys, gamepad). A second
token, the viewer's (`--viewer-token`), opens a page that may watch, not drive: every driving message
from it is refused (panel.py). Giving a viewer token makes a token needed on loopback too, since a
page opened with none would otherwise be an operator's.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
from typing import Final, Literal

PageRole = Literal["operator", "viewer"]
LOOPBACK_NAMES: Final = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARDS: Final = frozenset({"", "0.0.0.0", "::", "*"})


def host_name(host_header: str) -> str:
    """The name in a Host header, without port or IPv6 brackets, lower case."""
    host = host_header.strip().lower()
    if host.startswith("["):
        return host[1:].split("]", 1)[0]
    if host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.rstrip(".")


def is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def is_loopback(address: str) -> bool:
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


class Guard:
    """The access rules of one viz.

    Args:
        bind: the address the page is served on (`--host`).
        published_on: where the page is reachable from outside if not `bind` (compose: ZENSIM_BIND).
        allowed_hosts: extra Host names to accept (`*` accepts any).
        token: the access token; None makes one when a token is needed.
        always_token: need the token even on loopback (the secured mode).
        viewer_token: a second token, for pages that may watch, not drive; giving one makes tokens needed.

    Raises:
        ValueError: the viewer's token is the operator's.
    """

    def __init__(self, bind: str, published_on: str | None, allowed_hosts: tuple[str, ...], token: str | None,
                 always_token: bool = False, viewer_token: str | None = None) -> None:
        if viewer_token is not None and viewer_token == token:
            raise ValueError("the viewer's token must differ from the operator's (--viewer-token, --token)")
        self.viewer_token = viewer_token
        self.allowed = set(LOOPBACK_NAMES) | {h.lower() for h in allowed_hosts}
        for address in (bind, published_on or ""):
            if address not in WILDCARDS:
                self.allowed.add(host_name(address))
        # The name the printed URL uses: the address served on, or for a wildcard this machine's name,
        # which is then accepted too (a rebinding page cannot use our own host name).
        self.url_host = (published_on if published_on and published_on not in WILDCARDS else
                         bind if bind not in WILDCARDS else host_name(socket.gethostname()))
        self.allowed.add(host_name(self.url_host))
        self.any_host = "*" in self.allowed
        # Inside a container the page binds every interface but Docker may publish it on loopback only:
        # then the published address is what others can reach.
        reachable_on = published_on or bind
        needed = always_token or viewer_token is not None or not is_loopback(reachable_on)
        self.token: str | None = (token or secrets.token_urlsafe(24)) if needed else None
        self.cookie_name = "zensim_viz_token"
        """Set per port once bound: cookies are shared by every port of a host."""
        self.refused = 0
        """Requests refused (bad Host or token), for the log and tests."""

    def host_ok(self, host_header: str) -> bool:
        name = host_name(host_header)
        return self.any_host or name in self.allowed or is_ip_literal(name)

    def token_ok(self, given: str | None) -> bool:
        """Whether `given` (query argument or cookie) is a token (either role's); always True when none is needed."""
        return self.role_of(given) is not None

    def role_of(self, given: str | None) -> PageRole | None:
        """What a page with the token `given` may do: drive (operator) or watch (viewer); None: nothing."""
        if self.token is None:
            return "operator"
        if given is None:
            return None
        if hmac.compare_digest(given.encode(), self.token.encode()):
            return "operator"
        if self.viewer_token is not None and hmac.compare_digest(given.encode(), self.viewer_token.encode()):
            return "viewer"
        return None
