"""Typed settings for every service: defaults < environment (`ZENSIM_*`) < CLI flags.

Each service declares one frozen msgspec Struct. Its fields are the only
source of truth: the environment variable names, the `--flags` and their help
text are all generated from it. Nested structs (the shared `ZenohSettings`)
are flattened with their field name as prefix: `zenoh.mode` is
`ZENSIM_ZENOH_MODE` and `--zenoh-mode`.

What every service shares (`CommonSettings`: robot id, log level, Zenoh) keeps
one name for all, `ZENSIM_ROBOT_ID`. A service's own fields carry its prefix
(`env_prefix`): the sim's `rtf` is `ZENSIM_SIM_RTF`, the bridge's `rate_hz`
`ZENSIM_BRIDGE_RATE_HZ`, so no variable means two things and `zensim up` can
hand each service only its own. The flags stay short (`--rtf`): a command
line names its service already.

The unprefixed names of the first release (`ZENSIM_RTF`) still work for one
release, with a warning, except those that two services read with different
meanings (`AMBIGUOUS_LEGACY`), which are refused with the new names.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import sys
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final, Literal, TypeVar

import msgspec

from zensim.schemas.generate import attribute_docs
from zensim.schemas.keys import check_robot_id

logger = logging.getLogger(__name__)

ENV_PREFIX = "ZENSIM_"
SECRET_SUFFIXES = ("token", "password")
"""Settings whose values `describe` never logs."""
S = TypeVar("S", bound=msgspec.Struct)


class SettingsError(ValueError):
    """A setting that cannot be parsed or is out of range; names the field."""


ROUTER_PORT: Final = 7447
"""Zenoh's customary router port: where `zensim router` (and `zensim up`'s router) listen unless told."""
LOCAL_ROUTER_ENDPOINT: Final = f"tcp/127.0.0.1:{ROUTER_PORT}"
"""The router's default endpoint, and where peers with no endpoints meet on one machine."""
SECURE_LOCAL_ROUTER_ENDPOINT: Final = f"tls/127.0.0.1:{ROUTER_PORT}"
"""The router's default endpoint on a secured network (`zensim secure init`, `--secure-dir`)."""

ENDPOINT_PATTERN = re.compile(r"(?P<proto>[a-z0-9-]+)/(?P<address>[^#?]+)(?P<rest>[#?].*)?")
"""`proto/address[?metadata][#config]`, the shape of a zenoh locator."""
PORTED_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
"""Protocols whose address ends in `:port`."""
KNOWN_PROTOCOLS = PORTED_PROTOCOLS | {"unixsock-stream", "unixpipe", "serial", "vsock"}


def check_endpoint(endpoint: str) -> str:
    """Return `endpoint` when it is a zenoh endpoint zensim can use, else raise ValueError saying why.

    Zenoh itself would accept `tcp/127.0.0.1:99999` or `foo/bar` as a connect endpoint and then
    wait forever with no word, so the shape is checked here, where the setting's name is known.
    """
    match = ENDPOINT_PATTERN.fullmatch(endpoint)
    if not match:
        raise ValueError(f"endpoint {endpoint!r} is not of the form proto/address (e.g. {LOCAL_ROUTER_ENDPOINT})")
    proto, address = match["proto"], match["address"]
    if proto not in KNOWN_PROTOCOLS:
        raise ValueError(f"endpoint {endpoint!r}: unknown protocol {proto!r} (known: {', '.join(sorted(KNOWN_PROTOCOLS))})")
    if proto in PORTED_PROTOCOLS:
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ValueError(f"endpoint {endpoint!r}: expected {proto}/host:port with a port in 0..65535")
    return endpoint


class ZenohSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How a service joins the Zenoh network (the flags of zenoh's own examples).

    Secure by default: a peer with no endpoints listens on loopback only and
    no multicast scouting runs (docs/security.md).
    """

    # Fields whose flag and variable carry no `zenoh` prefix: `--secure-dir`, `ZENSIM_SECURE_DIR`.
    unprefixed: ClassVar[frozenset[str]] = frozenset({"secure_dir"})

    mode: Literal["peer", "client", "router"] = "peer"
    """Zenoh session mode."""
    connect: tuple[str, ...] = ()
    """Endpoints to connect to, comma-separated (e.g. tcp/router:7447)."""
    listen: tuple[str, ...] = ()
    """Endpoints to listen on, comma-separated (e.g. tcp/0.0.0.0:7447)."""
    config_file: str | None = None
    """A zenoh JSON5 config file; the settings above override its fields."""
    multicast_scouting: bool = False
    """Find peers by UDP multicast on every interface (answers the whole LAN); off unless asked."""
    secure_dir: str | None = None
    """A folder made by `zensim secure init`: TLS links, passwords and access roles (docs/security.md)."""

    def __post_init__(self) -> None:
        for field, endpoints in (("connect", self.connect), ("listen", self.listen)):
            for endpoint in endpoints:
                try:
                    check_endpoint(endpoint)
                except ValueError as exc:
                    raise ValueError(f"{exc} - at --zenoh-{field} / {ENV_PREFIX}ZENOH_{field.upper()}") from None


def zero_or_at_least(value: float, floor: float, flag: str) -> None:
    """A rate or factor where 0 means "off" or "unbounded" and anything else must be sane: 1e-300 passed a
    `ge=0` check and then a service never published again. Raises ValueError naming the flag."""
    if value != 0 and value < floor:
        raise ValueError(f"must be 0 or at least {floor:g}, got {value:g} - at --{flag.replace('_', '-')}")


class CommonSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings every service has; their variables carry no service prefix."""

    env_prefix: ClassVar[str] = ""
    """The service's prefix for its own fields' variables (`SIM` -> `ZENSIM_SIM_*`)."""

    robot_id: str = "g1"
    """Robot id: the `{robot}` chunk of every key (zensim/{robot}/...)."""
    log_level: str = "INFO"
    """Python log level (DEBUG, INFO, WARNING, ERROR); zenoh's own logs follow RUST_LOG."""
    zenoh: ZenohSettings = ZenohSettings()
    """Zenoh session settings."""


SHARED_FIELDS = frozenset(field.name for field in msgspec.structs.fields(CommonSettings))
"""Top-level fields whose variables every service shares: ZENSIM_ROBOT_ID, ZENSIM_LOG_LEVEL, ZENSIM_ZENOH_*."""

SHARED_NAMES = frozenset({"secure_dir"})
"""Settings that keep one unprefixed variable wherever they appear (`ZENSIM_SECURE_DIR` for every service and up)."""

FIRST_RELEASE_FIELDS: Final[dict[str, frozenset[str]]] = {
    "SIM": frozenset({"robot", "urdf", "control", "mode", "timestep_s", "rtf", "state_rate_hz", "state_clock",
                      "status_rate_hz", "watchdog_timeout_s", "auto_reset_on_fall", "fall_reset_delay_s", "max_kp",
                      "max_kd", "paused"}),
    "BRIDGE": frozenset({"rate_hz", "targets_rate_hz", "slew_rad_s", "info_timeout_s", "robot", "urdf", "control"}),
    "VIZ": frozenset({"host", "port", "urdf", "rate_hz", "ghost", "ghost_offset_m", "query_timeout_s"}),
    "ROUTER": frozenset({"cmd_rate_limit_hz", "input_size_limit_bytes"}),
    "UP": frozenset({"router_endpoint", "viz"}),
}
"""By service prefix, the fields the first release read under unprefixed names (`ZENSIM_RTF`): the
settings as they were before names carried a service's prefix (git af9d6c4^; the project has no tags).
Only these keep their old name for this release, with a warning. Fields added since (the sim's clock
and world, the viz's token, `zensim up --unitree`, ...) and newer services never had an unprefixed
name: inventing one made `ZENSIM_UNITREE=1`, compose's build switch, also turn on `zensim up --unitree`."""

AMBIGUOUS_LEGACY: dict[str, tuple[str, ...]] = {
    "ZENSIM_RATE_HZ": ("ZENSIM_BRIDGE_RATE_HZ", "ZENSIM_VIZ_RATE_HZ"),
    "ZENSIM_URDF": ("ZENSIM_SIM_URDF", "ZENSIM_BRIDGE_URDF", "ZENSIM_VIZ_URDF"),
    "ZENSIM_ROBOT": ("ZENSIM_SIM_ROBOT", "ZENSIM_BRIDGE_ROBOT"),
    "ZENSIM_CONTROL": ("ZENSIM_SIM_CONTROL", "ZENSIM_BRIDGE_CONTROL"),
}
"""First-release names that several services read with different meanings: refused, naming the new ones
(`ZENSIM_RATE_HZ=500 zensim up` meant the bridge's rate and stopped the viz, whose limit is 240)."""


def env_names(cls: type[msgspec.Struct]) -> dict[str, str | None]:
    """Every variable `cls` reads: {variable: its first-release name, or None when it has none}."""
    return {env: legacy for _, _, _, _, env, legacy in _fields_with_env(cls)}


def _fields_with_env(cls: type[msgspec.Struct]) -> list[tuple[str, tuple[str, ...], Any, str, str, str | None]]:
    """(flat name, path, type, help, variable, first-release variable or None) for every leaf field."""
    prefix = getattr(cls, "env_prefix", "")
    released = FIRST_RELEASE_FIELDS.get(prefix, frozenset())
    out: list[tuple[str, tuple[str, ...], Any, str, str, str | None]] = []
    for name, path, typ, doc in _flat_fields(cls):
        plain = ENV_PREFIX + name.upper()
        if path[0] in SHARED_FIELDS or name in SHARED_NAMES or not prefix:
            out.append((name, path, typ, doc, plain, None))
        else:
            out.append((name, path, typ, doc, f"{ENV_PREFIX}{prefix}_{name.upper()}", plain if name in released else None))
    return out


def _flat_fields(cls: type[msgspec.Struct], prefix: str = "") -> list[tuple[str, tuple[str, ...], Any, str]]:
    """(flat name, path of field names, type, help) for every leaf field."""
    docs = attribute_docs(cls)
    flat = []
    for field in msgspec.structs.fields(cls):
        path = (field.name,)
        if isinstance(field.type, type) and issubclass(field.type, msgspec.Struct):
            keep: frozenset[str] = getattr(field.type, "unprefixed", frozenset())
            for name, sub_path, typ, doc in _flat_fields(field.type, f"{prefix}{field.name}_"):
                flat.append((sub_path[-1] if sub_path[-1] in keep else name, path + sub_path, typ, doc))
        else:
            flat.append((f"{prefix}{field.name}", path, field.type, docs.get(field.name, "")))
    return flat


def _is_sequence(typ: Any) -> bool:
    return getattr(typ, "__origin__", None) in (tuple, list)


def _raw_value(raw: str, typ: Any) -> Any:
    if _is_sequence(typ):
        return [item.strip() for item in raw.split(",") if item.strip()]
    return raw


def _set_path(tree: dict, path: tuple[str, ...], value: Any) -> None:
    for name in path[:-1]:
        tree = tree.setdefault(name, {})
    tree[path[-1]] = value


def load_settings(
    cls: type[S],
    argv: Sequence[str] | None = None,
    env: Mapping[str, str] | None = None,
    prog: str | None = None,
) -> S:
    """Build `cls` from its defaults, then `ZENSIM_*` variables, then CLI flags.

    Raises:
        SettingsError: a value does not parse or is out of range; names the field.
        SystemExit: from argparse, on --help or an unknown flag.
    """
    env = os.environ if env is None else env
    fields = _fields_with_env(cls)
    parser = argparse.ArgumentParser(prog=prog, description=(cls.__doc__ or "").strip())
    for name, _, typ, doc, env_name, _ in fields:
        parser.add_argument(
            "--" + name.replace("_", "-"),
            dest=name,
            metavar="LIST" if _is_sequence(typ) else "VALUE",
            help=f"{doc} [env {env_name}]",
        )
    args = parser.parse_args(list(argv) if argv is not None else None)

    # Start from the defaults of `cls` itself, so a nested default (the
    # router's listen endpoint) survives when only a sibling field is set.
    tree: dict = msgspec.to_builtins(cls())
    for name, path, typ, _, env_name, legacy in fields:
        raw = getattr(args, name)
        if raw is None:
            raw = env.get(env_name) or _legacy_value(env, env_name, legacy)
        if raw is not None:
            _set_path(tree, path, _raw_value(raw, typ))
    try:
        settings = msgspec.convert(tree, cls, strict=False)
    except msgspec.ValidationError as exc:
        raise SettingsError(f"bad setting: {_flag_names(str(exc), {f[0]: f[4] for f in fields})}") from None
    for name, path, _, _, env_name, _ in fields:
        value: Any = settings
        for part in path:
            value = getattr(value, part)
        values = value if isinstance(value, tuple) else (value,)
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise SettingsError(f"bad setting: {value} is not a finite number - --{name.replace('_', '-')} / {env_name}")
    return settings


def _legacy_value(env: Mapping[str, str], env_name: str, legacy: str | None) -> str | None:
    """The value of a first-release variable name: refused when ambiguous, else used with a warning."""
    if legacy is None or not env.get(legacy):
        return None
    if legacy in AMBIGUOUS_LEGACY:
        raise SettingsError(f"{legacy} is read by several services with different meanings and is no longer "
                            f"accepted: use {' or '.join(AMBIGUOUS_LEGACY[legacy])}")
    logger.warning("%s is deprecated and goes away in the next release: use %s", legacy, env_name)
    return env[legacy]


def _flag_names(message: str, env_names_by_flat: Mapping[str, str]) -> str:
    """Turn msgspec's `$.zenoh.mode` paths into the flag a user typed."""
    if "$." not in message:
        return message
    if " - at --" in message:  # the check named the flag itself (a nested struct's __post_init__)
        return message.split(" - at `$.")[0]
    head, path = message.rsplit("$.", 1)
    name = path.rstrip("`").replace(".", "_")
    head = head.rstrip("`")
    return f"{head}--{name.replace('_', '-')} / {env_names_by_flat.get(name, ENV_PREFIX + name.upper())}"


def describe(settings: msgspec.Struct) -> str:
    """One log line with every resolved setting."""
    return " ".join(f"{k}={v!r}" for k, v in _flatten_values(msgspec.structs.asdict(settings)))


def _flatten_values(tree: dict, prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for key, value in tree.items():
        if isinstance(value, msgspec.Struct):
            out.extend(_flatten_values(msgspec.structs.asdict(value), f"{prefix}{key}_"))
        elif key.endswith(SECRET_SUFFIXES) and value:
            out.append((prefix + key, "<hidden>"))  # logs are read by more people than the page's users
        else:
            out.append((prefix + key, value))
    return out


def settings_table(cls: type[msgspec.Struct]) -> str:
    """A Markdown table of every setting: variable, flag, default, meaning (for the service READMEs)."""
    defaults = msgspec.to_builtins(cls())
    rows = ["| environment | flag | default | meaning |", "|---|---|---|---|"]
    for name, path, _, doc, env_name, _ in _fields_with_env(cls):
        value: Any = defaults
        for part in path:
            value = value.get(part) if isinstance(value, dict) else None
        shown = ",".join(map(str, value)) if isinstance(value, (list, tuple)) else ("" if value is None else str(value).lower() if isinstance(value, bool) else value)
        meaning = " ".join(doc.split())  # a docstring of several lines is one table row
        rows.append(f"| `{env_name}` | `--{name.replace('_', '-')}` | `{shown}` | {meaning} |")
    return "\n".join(rows) + "\n"


def check_secure(settings: ZenohSettings) -> None:
    """Fail fast on a secured setup that cannot work: a missing folder, plain endpoints, a config file too.

    Raises:
        SettingsError: names the setting.
    """
    if not settings.secure_dir:
        return
    if not os.path.isdir(settings.secure_dir):
        raise SettingsError(f"--secure-dir / ZENSIM_SECURE_DIR {settings.secure_dir!r} is not a folder "
                            "(make one with `zensim secure init DIR`)")
    if settings.config_file:
        raise SettingsError("give either --secure-dir or --zenoh-config-file, not both")
    plain = [e for e in (*settings.connect, *settings.listen) if not e.startswith("tls/")]
    if plain:
        raise SettingsError(f"with --secure-dir every endpoint is tls/, not {', '.join(plain)}")


def settings_or_exit(cls: type[S], argv: Sequence[str] | None, prog: str) -> S:
    """`load_settings` for a command's main: a bad setting prints one line and exits with code 2."""
    try:
        settings = load_settings(cls, argv, prog=prog)
        robot_id = getattr(settings, "robot_id", None)
        if robot_id is not None:
            check_robot_id(robot_id)
        zenoh_settings = getattr(settings, "zenoh", None)
        if isinstance(zenoh_settings, ZenohSettings):
            check_secure(zenoh_settings)
    except (SettingsError, ValueError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return settings
