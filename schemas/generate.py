"""Write the JSON Schema of every wire message into schemas/jsonschema/, and the registry's tables into docs.

Run `python -m zensim.schemas.generate` after changing messages.py or
topics.py; a test fails while the files are stale. Each table goes between
two marker lines, when run from a checkout (an installed package has no docs):
`<!-- topics:begin -->` / `<!-- topics:end -->` (the protocol table, docs/protocol.md),
`<!-- roles:begin -->` / `<!-- roles:end -->` (the role table, docs/security.md),
`<!-- keys:ROLE:begin -->` / `<!-- keys:ROLE:end -->` (the keys one service's role
writes and reads, in its README).
"""

from __future__ import annotations

import ast
import inspect
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

import msgspec

from . import messages
from .messages import WIRE_TYPES, Message
from .topics import protocol_table, role_table, service_key_table

SCHEMA_DIR = Path(__file__).resolve().parent / "jsonschema"  # the checkout's folder, not the install's link to it
CHECKOUT = Path(__file__).resolve().parent.parent
SECTION = re.compile(r"<!-- (?P<name>[a-z0-9:_-]+):begin -->\n.*?<!-- (?P=name):end -->\n", re.DOTALL)


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> the attribute docstring written under it in `cls`'s source.

    msgspec does not read attribute docstrings, so they are lifted from the
    source: the class stays the only place a field is described. Used for the
    JSON Schemas here and for the settings' --help.
    """
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass.__module__ in ("builtins", "msgspec"):
            continue
        try:
            node = ast.parse(inspect.getsource(klass).strip()).body[0]
        except (OSError, TypeError, IndexError):
            continue
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt, following in zip(node.body, node.body[1:]):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[stmt.target.id] = following.value.value
    return docs


def _annotate(schema: dict) -> dict:
    for name, definition in schema.get("$defs", {}).items():
        properties = definition.get("properties", {})
        for field, text in attribute_docs(getattr(messages, name)).items():
            if field in properties:
                properties[field]["description"] = text
        if "type" in properties:
            # The key already says the type: readers accept JSON without the tag.
            properties["type"]["description"] = "Optional type tag; writers set it."
            definition["required"] = [f for f in definition.get("required", []) if f != "type"]
    return schema


def tag_of(message_type: type[Message]) -> str:
    """The stable tag of a message type (also its schema file name)."""
    return msgspec.inspect.type_info(message_type).tag  # type: ignore[attr-defined]


def render() -> dict[str, str]:
    """File name -> JSON Schema text, one file per wire message."""
    files = {}
    for message_type in WIRE_TYPES:
        schema = _annotate(msgspec.json.schema(message_type))
        files[f"{tag_of(message_type)}.json"] = json.dumps(schema, indent=2, sort_keys=True) + "\n"
    return files


def section_renderer(name: str) -> Callable[[], str]:
    """What renders the section called `name` (`topics`, `roles`, `keys:<role>`); KeyError if none does."""
    if name == "topics":
        return protocol_table
    if name == "roles":
        return role_table
    if name.startswith("keys:"):
        role = name.split(":", 1)[1]
        service_key_table(role)  # raises KeyError for an unknown role
        return lambda: service_key_table(role)
    raise KeyError(name)


def generated_docs() -> list[Path]:
    """The docs of the checkout that hold generated sections: docs/*.md and every services/*/README.md."""
    candidates = [*sorted((CHECKOUT / "docs").glob("*.md")), *sorted((CHECKOUT / "services").glob("*/README.md"))]
    return [doc for doc in candidates if sections(doc.read_text())]


def sections(doc: str) -> list[str]:
    """The names of the generated sections in `doc`."""
    return [m.group("name") for m in SECTION.finditer(doc)]


def with_sections(doc: str) -> str:
    """`doc` with every generated section (between its marker lines) rendered anew from the registry."""
    def render_one(match: re.Match[str]) -> str:
        name = match.group("name")
        return f"<!-- {name}:begin -->\n{section_renderer(name)()}<!-- {name}:end -->\n"

    return SECTION.sub(render_one, doc)


def main() -> int:
    SCHEMA_DIR.mkdir(exist_ok=True)
    for name, text in render().items():
        (SCHEMA_DIR / name).write_text(text)
        print(SCHEMA_DIR / name)
    for doc in generated_docs():
        doc.write_text(with_sections(doc.read_text()))
        print(doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
