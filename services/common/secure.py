"""Secured Zenoh links built on Zenoh's own TLS, user/password authentication and access control.

`zensim secure init DIR` (zensim/secure.py) writes a folder:

    router.json5     the router: tls/ listener, mutual TLS, the password dictionary, the access rules
    users.txt        user:password lines the router checks (zenoh's usrpwd dictionary_file)
    <role>.json5     one client config per role of the topic registry (schemas/topics.py ROLES): each
                     service's own (sim, bridge, viz, unitree, ros1, recorder, replay) and ready-made
                     ones for people and tools (operator, viewer); its user, password and certificate
    <name>.json5     one more per named client (`--client NAME=ROLE:ID,...`): a person or tool with a client
                     role's rules on robots of its own (two operators, each of one robot of a world)
    ca.pem           the CA certificate (to check the router's certificate by hand)

Every client config is self-contained (certificates inline as base64), so any
Zenoh client in any language loads it as is and adds only connect/endpoints.
Nothing here does cryptography itself: the `cryptography` package makes the
keys and certificates, zenoh does TLS, authentication and access control.
"""

from __future__ import annotations

import base64
import datetime
import ipaddress
import json
import os
import secrets
import stat
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import zenoh

from zensim.common.settings import ROUTER_PORT, SECURE_LOCAL_ROUTER_ENDPOINT
from zensim.schemas.keys import ROOT, check_robot_id
from zensim.schemas.topics import EVERY_ROLE_WATCHES, ROLE_NAMES, ROLES, ROUTER_ALIVE, Role, role

DEFAULT_HOSTS: Final = ("localhost", "127.0.0.1", "::1", "router")
"""Names every router certificate carries: this machine, and compose's service name `router`."""
USERS_FILE: Final = "users.txt"
CERT_DAYS: Final = 825


class SecureConfigError(ValueError):
    """A secure folder that is missing a file or is used with plain endpoints; names what is wrong."""


RESERVED_NAMES: Final = frozenset((*ROLE_NAMES, "router", "ca", "users"))
"""Names a named client cannot take: a role's (its file and user), the router's, the folder's other files'."""


@dataclass(frozen=True)
class Client:
    """One more credential with a client role's rules (`zensim secure init --client NAME=ROLE:ID,...`).

    A role is one credential, with one scope; a named client is another user and certificate with the same
    rules on robots of its own, so two people on one router can each drive their own robots (each robot of a
    world, for instance).

    Args:
        name: its user name, `zensim-<name>` certificate and `<name>.json5` file.
        role: the client role whose rules it has (operator, viewer).
        robots: the robot ids it may act on; empty: every robot.
    """

    name: str
    role: str
    robots: tuple[str, ...] = ()

    def check(self) -> None:
        """Raises SecureConfigError naming what is wrong: a bad or reserved name, a service role, a bad robot id."""
        try:
            check_robot_id(self.name)  # the same alphabet: it becomes a file, a user and a certificate name
        except ValueError:
            raise SecureConfigError(f"--client {self.name[:80]!r}: a name is 1 to 64 characters of [a-z0-9_-]") from None
        try:
            for robot in self.robots:
                check_robot_id(robot)
            kind = role(self.role).kind
        except (ValueError, KeyError) as exc:
            raise SecureConfigError(f"--client {self.name}: {str(exc).strip(chr(34))}") from None
        if self.name in RESERVED_NAMES:
            raise SecureConfigError(f"--client {self.name}: the name is taken (roles and files: "
                                    f"{', '.join(sorted(RESERVED_NAMES))})")
        if kind != "client":
            clients = ", ".join(r.name for r in ROLES if r.kind == "client")
            raise SecureConfigError(f"--client {self.name}: {self.role} is a service's role; a named client takes a "
                                    f"client role ({clients})")


# ------------------------------------------------------------------------------------- access rules
# Zenoh's access-control messages for each way a role uses a key (topics.Role's fields): what the
# role may send to the router (ingress), and what the router may send it (egress) so that it works.
RULES_BY_USE: Final[dict[str, list[tuple[str, list[str]]]]] = {
    "publishes": [("ingress", ["put"])],
    "subscribes": [("ingress", ["declare_subscriber"]), ("egress", ["put"])],
    "serves": [("ingress", ["declare_queryable", "reply"]), ("egress", ["query"])],
    "queries": [("ingress", ["query"]), ("egress", ["reply"])],
    "tokens": [("ingress", ["liveliness_token"])],
}
EVERY_ROLE_RULES: Final = [
    ("ingress", ["declare_liveliness_subscriber", "liveliness_query"], list(EVERY_ROLE_WATCHES)),
    ("egress", ["liveliness_token", "liveliness_query"], list(EVERY_ROLE_WATCHES)),
    # Declarations the router forwards: a publisher learns who listens. Data itself is filtered above.
    ("egress", ["declare_subscriber", "declare_queryable", "declare_liveliness_subscriber"], ["**"]),
]
ALL_ROBOTS: Final = "*"
ROUTER_WATCH_RULES: Final = [
    # The router's own token (outside every robot's keys): every role may see that the router is up.
    ("ingress", ["declare_liveliness_subscriber", "liveliness_query"]),
    ("egress", ["liveliness_token", "liveliness_query"]),
]


ROS2_DECLARATIONS: Final = ("egress", ["declare_subscriber", "declare_queryable", "declare_liveliness_subscriber"])
"""Declarations the router forwards on the ROS keys: a publisher learns who listens, a querier who answers."""
ROS2_WRITE_RULES: Final = [
    ("ingress", ["put", "declare_subscriber", "declare_queryable", "reply", "query", "liveliness_token",
                 "declare_liveliness_subscriber", "liveliness_query"]),
    ("egress", ["put", "query", "reply", "liveliness_token", "liveliness_query"]),
    ROS2_DECLARATIONS,
]
ROS2_READ_RULES: Final = [
    # A reading ROS 2 node still announces itself and its subscriptions (tokens) and asks latched topics'
    # caches (queries); it never puts data nor answers a query.
    ("ingress", ["declare_subscriber", "query", "liveliness_token", "declare_liveliness_subscriber",
                 "liveliness_query"]),
    ("egress", ["put", "reply", "liveliness_token", "liveliness_query"]),
    ROS2_DECLARATIONS,
]
DEFAULT_ROS_DOMAINS: Final = (0,)


def ros2_keys(domain: int) -> list[str]:
    """rmw_zenoh's keys of one ROS domain: data, the advanced publishers' caches and tokens (`@adv` is a
    verbatim chunk that `**` does not cross), and the graph's liveliness tokens."""
    return [f"{domain}/**", f"{domain}/**/@adv/**", f"@ros2_lv/{domain}/**"]


def role_rules(role: Role) -> list[tuple[str, list[str], list[str]]]:
    """(flow, messages, keys under `zensim/{robot}/`) the router allows `role`; everything else is denied."""
    rules = [(flow, messages, list(getattr(role, use))) for use, pairs in RULES_BY_USE.items()
             for flow, messages in pairs if getattr(role, use)]
    return rules + EVERY_ROLE_RULES


def access_control(robots: Mapping[str, Sequence[str]] | None = None,
                   ros_domains: Sequence[int] = DEFAULT_ROS_DOMAINS, clients: Sequence[Client] = ()) -> dict:
    """Zenoh's `access_control` block: one subject per role and per named client (its user name and
    certificate name).

    Args:
        robots: role -> the robot ids its credential may act on; a role not named acts on every robot.
        ros_domains: the ROS domains whose rmw_zenoh keys roles with `ros2` access may use.
        clients: named clients, each with its role's rules on its own robots.
    """
    robots = robots or {}
    block: dict = {"enabled": True, "default_permission": "deny", "rules": [], "subjects": [], "policies": []}
    for each in ROLES:
        _add_subject(block, each.name, each.name, each, robots.get(each.name, ()), ros_domains)
    for client in clients:  # rule ids prefixed apart: a client's name never makes a role's rule id
        _add_subject(block, client.name, f"client-{client.name}", role(client.role), client.robots, ros_domains)
    return block


def _add_subject(block: dict, name: str, rule_prefix: str, of: Role, robots: Sequence[str],
                 ros_domains: Sequence[int]) -> None:
    """One subject (user `name`, certificate `zensim-<name>`) with role `of`'s rules on `robots` (all if none)."""
    scope = [check_robot_id(r) for r in robots] or [ALL_ROBOTS]
    ids: list[str] = []

    def allow(suffix: str, flow: str, messages: list[str], keys: list[str]) -> None:
        ids.append(f"{rule_prefix}-{suffix}")
        block["rules"].append({"id": ids[-1], "flows": [flow], "permission": "allow", "messages": messages,
                               "key_exprs": keys})

    for n, (flow, messages, keys) in enumerate(role_rules(of)):
        allow(str(n), flow, messages, [f"{ROOT}/{robot}/{key}" for robot in scope for key in keys])
    for n, (flow, messages) in enumerate(ROUTER_WATCH_RULES):
        allow(f"router-{n}", flow, messages, [ROUTER_ALIVE.full_key()])
    if of.ros2:
        for n, (flow, messages) in enumerate(ROS2_WRITE_RULES if of.ros2 == "write" else ROS2_READ_RULES):
            allow(f"ros2-{n}", flow, messages, [key for domain in ros_domains for key in ros2_keys(domain)])
    block["subjects"].append({"id": name, "usernames": [name], "cert_common_names": [cert_name(name)]})
    block["policies"].append({"id": name, "rules": ids, "subjects": [name]})


def cert_name(role: str) -> str:
    return f"zensim-{role}"


# ------------------------------------------------------------------------------------- certificates
def _b64(pem: bytes) -> str:
    return base64.b64encode(pem).decode()


def _new_key():  # noqa: ANN202 - a cryptography private key
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key) -> bytes:  # noqa: ANN001
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert(subject_cn: str, key, issuer_cn: str, issuer_key, days: int, *, ca: bool = False,  # noqa: ANN001
          hosts: tuple[str, ...] = (), client: bool = False):  # noqa: ANN202
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject_cn)]))
        .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer_cn)]))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
    )
    if ca:
        builder = builder.add_extension(
            x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                          key_encipherment=False, data_encipherment=False, key_agreement=False,
                          encipher_only=False, decipher_only=False), critical=True)
    else:
        names: list[x509.GeneralName] = []
        for host in hosts:
            try:
                names.append(x509.IPAddress(ipaddress.ip_address(host)))
            except ValueError:
                names.append(x509.DNSName(host))
        if client:
            names.append(x509.DNSName(subject_cn))
        builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
        usage = ExtendedKeyUsageOID.CLIENT_AUTH if client else ExtendedKeyUsageOID.SERVER_AUTH
        builder = builder.add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
    from cryptography.hazmat.primitives import serialization

    return builder.sign(issuer_key, hashes.SHA256()).public_bytes(serialization.Encoding.PEM)


def _write(path: Path, text: str, private: bool) -> None:
    path.write_text(text)
    path.chmod(0o600 if private else 0o644)


def _json5(header: str, config: dict) -> str:
    return "// " + "\n// ".join(header.splitlines()) + "\n" + json.dumps(config, indent=2) + "\n"


SESSION_LOG_TARGET: Final = "zenoh::api::session"
"""Where zenoh logs a session's whole Config (password included) at debug level when it opens."""


def password_printing_directive(rust_log: str) -> str | None:
    """The RUST_LOG directive that would print a session's password in clear, or None.

    tracing's filter enables a target by string prefix (`zenoh=debug` covers `zenoh::api::session`);
    a directive with no target sets the level of everything. The router's access-control audit
    (`zenoh::net::routing::interceptor::access_control=trace`) does not cover it.
    """
    for directive in rust_log.split(","):
        target, _, level = directive.strip().rpartition("=")
        if not target and "=" not in directive:
            target, level = "", directive.strip()
        target = target.split("[", 1)[0]
        if level.strip().lower() in ("debug", "trace") and SESSION_LOG_TARGET.startswith(target):
            return directive.strip()
    return None


def check_own_folder(folder: Path) -> None:
    """An existing folder must be ours alone: its owner could otherwise swap users.txt or router.json5 later
    (whoever owns a folder may rename and replace the files in it, whatever their own modes).

    Raises:
        SecureConfigError: a symlink, a folder another user owns, or one others may write to.
    """
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise SecureConfigError(f"{folder} is a symbolic link: give a real folder (or a new name)")
    if not stat.S_ISDIR(st.st_mode):
        raise SecureConfigError(f"{folder} is not a folder")
    if st.st_uid != os.geteuid():
        raise SecureConfigError(f"{folder} belongs to another user (uid {st.st_uid}), who could swap its files "
                                "later: choose a new folder of your own")
    if st.st_mode & 0o022:
        raise SecureConfigError(f"{folder} is writable by others (mode {stat.S_IMODE(st.st_mode):o}), who could swap "
                                "its files later: choose a new folder (or chmod 700 it first)")


def init(folder: Path, hosts: tuple[str, ...] = (), listen: tuple[str, ...] = (SECURE_LOCAL_ROUTER_ENDPOINT,),
         days: int = CERT_DAYS, robots: Mapping[str, Sequence[str]] | None = None,
         ros_domains: Sequence[int] = DEFAULT_ROS_DOMAINS, clients: Sequence[Client] = ()) -> list[Path]:
    """Make a CA, the router's certificate, one certificate and password per role, and the configs.

    The CA key is not kept: run `init` again (into a fresh folder) to change hosts or roles.

    Args:
        folder: where to write; must not exist or be empty.
        hosts: extra DNS names or IP addresses the router is reached at (DEFAULT_HOSTS are always in).
        listen: the router's default tls/ listen endpoints (`--zenoh-listen` overrides them).
        days: certificate lifetime.
        robots: role -> the robot ids its credential may act on (default: every robot).
        ros_domains: the ROS domains whose rmw_zenoh keys `zensim ros2` and ROS 2 nodes may use.
        clients: named clients: one more credential each (`<name>.json5`), a client role's rules on its robots.

    Returns:
        The files written.

    Raises:
        SecureConfigError: `folder` is not empty, `robots` names an unknown role or a bad robot id, or a
            named client is bad (Client.check) or named twice.
    """
    for client in clients:
        client.check()
    names = [client.name for client in clients]
    if len(set(names)) != len(names):
        raise SecureConfigError(f"--client names must be unique: {', '.join(names)}")
    for name, ids in (robots or {}).items():
        if name not in ROLE_NAMES:
            raise SecureConfigError(f"no role {name!r} to scope; roles: {', '.join(ROLE_NAMES)}")
        for robot in ids:
            try:
                check_robot_id(robot)
            except ValueError as exc:
                raise SecureConfigError(str(exc)) from None
    check_own_folder(folder)
    if folder.exists() and any(folder.iterdir()):
        raise SecureConfigError(f"{folder} is not empty: choose a new folder")
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o700)
    ca_key = _new_key()
    ca_pem = _cert("zensim CA", ca_key, "zensim CA", ca_key, days, ca=True)
    all_hosts = tuple(dict.fromkeys((*DEFAULT_HOSTS, *hosts)))
    router_key = _new_key()
    router_pem = _cert(cert_name("router"), router_key, "zensim CA", ca_key, days, hosts=all_hosts)
    written: list[Path] = []

    def put(name: str, text: str, private: bool = True) -> None:
        _write(folder / name, text, private)
        written.append(folder / name)

    put("ca.pem", ca_pem.decode(), private=False)
    passwords = {name: secrets.token_urlsafe(24) for name in (*ROLE_NAMES, *names)}
    put(USERS_FILE, "".join(f"{role}:{pw}\n" for role, pw in passwords.items()))
    router = {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "transport": {
            "link": {"tls": {"root_ca_certificate_base64": _b64(ca_pem),
                             "listen_certificate_base64": _b64(router_pem),
                             "listen_private_key_base64": _b64(_key_pem(router_key)),
                             "enable_mtls": True}},
            # zensim sets the absolute path at start; zenohd needs it edited to where the file is.
            "auth": {"usrpwd": {"dictionary_file": USERS_FILE}},
        },
        "access_control": access_control(robots, ros_domains, clients),
    }
    put("router.json5", _json5(f"zensim router, secured (hosts: {', '.join(all_hosts)}). Keep private.", router))
    roles_of = {**{name: name for name in ROLE_NAMES}, **{client.name: client.role for client in clients}}
    for name, its_role in roles_of.items():
        key = _new_key()
        pem = _cert(cert_name(name), key, "zensim CA", ca_key, days, client=True)
        config = {
            "mode": "client",
            "transport": {
                "link": {"tls": {"root_ca_certificate_base64": _b64(ca_pem),
                                 "connect_certificate_base64": _b64(pem),
                                 "connect_private_key_base64": _b64(_key_pem(key)),
                                 "enable_mtls": True}},
                "auth": {"usrpwd": {"user": name, "password": passwords[name]}},
            },
        }
        what = f"zensim {name} credentials" if name == its_role else f"zensim {name} credentials (role {its_role})"
        put(f"{name}.json5", _json5(
            f"{what}: a Zenoh client config; add connect/endpoints, e.g.\n"
            f'  "connect": {{"endpoints": ["tls/<router host>:{ROUTER_PORT}"]}}\nKeep private.', config))
    return written


# ------------------------------------------------------------------------------------------ loading
def role_config(folder: str | Path, role: str) -> zenoh.Config:
    """The zenoh.Config of `role` from a folder made by `init`.

    Raises:
        SecureConfigError: the folder lacks the role's file.
    """
    folder = Path(folder)
    path = folder / f"{role}.json5"
    if not path.is_file():
        raise SecureConfigError(f"{path} not found: make the folder with `zensim secure init {folder}`")
    conf = zenoh.Config.from_file(str(path))
    if role == "router":
        users = folder / USERS_FILE
        if not users.is_file():
            raise SecureConfigError(f"{users} not found")
        conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users.resolve())))
    return conf
