"""Typed settings for every service: defaults < environment (`ZENSIM_*`) < CLI flags.

Each service declares one frozen msgspec Struct. Its fields are the only
source of truth: the environment variable names, the `--flags` and their help
text are all generated from it. Nested structs (the shared `ZenohSettings`)
are flattened with their field name as prefix: `zenoh.mode` is
`ZENSIM_ZENOH_MODE` and `--zenoh-mode`.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Literal, TypeVar

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


class CommonSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Settings every service has."""

    robot_id: str = "g1"
    """Robot id: the `{robot}` chunk of every key (zensim/{robot}/...)."""
    log_level: str = "INFO"
    """Python log level (DEBUG, INFO, WARNING, ERROR); zenoh's own logs follow RUST_LOG."""
    zenoh: ZenohSettings = ZenohSettings()
    """Zenoh session settings."""


def _flat_fields(cls: type[msgspec.Struct], prefix: str = "") -> list[tuple[str, tuple[str, ...], Any, str]]:
    """(flat name, path of field names, type, help) for every leaf field."""
    docs = attribute_docs(cls)
    flat = []
    for field in msgspec.structs.fields(cls):
        path = (field.name,)
        if isinstance(field.type, type) and issubclass(field.type, msgspec.Struct):
            keep = getattr(field.type, "unprefixed", frozenset())
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
    fields = _flat_fields(cls)
    parser = argparse.ArgumentParser(prog=prog, description=(cls.__doc__ or "").strip())
    for name, _, typ, doc in fields:
        env_name = ENV_PREFIX + name.upper()
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
    for name, path, typ, _ in fields:
        raw = getattr(args, name)
        if raw is None:
            raw = env.get(ENV_PREFIX + name.upper()) or None
        if raw is not None:
            _set_path(tree, path, _raw_value(raw, typ))
    try:
        return msgspec.convert(tree, cls, strict=False)
    except msgspec.ValidationError as exc:
        raise SettingsError(f"bad setting: {_flag_names(str(exc))}") from None


def _flag_names(message: str) -> str:
    """Turn msgspec's `$.zenoh.mode` paths into the flag a user typed."""
    if "$." not in message:
        return message
    head, path = message.rsplit("$.", 1)
    name = path.rstrip("`").replace(".", "_")
    head = head.rstrip("`")
    return f"{head}--{name.replace('_', '-')} / {ENV_PREFIX}{name.upper()}"


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
    for name, path, _, doc in _flat_fields(cls):
        value: Any = defaults
        for part in path:
            value = value.get(part) if isinstance(value, dict) else None
        shown = ",".join(map(str, value)) if isinstance(value, (list, tuple)) else ("" if value is None else str(value).lower() if isinstance(value, bool) else value)
        rows.append(f"| `{ENV_PREFIX}{name.upper()}` | `--{name.replace('_', '-')}` | `{shown}` | {doc} |")
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
