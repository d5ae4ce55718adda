"""Write the JSON Schema of every wire message into schemas/jsonschema/, and the protocol table into docs.

Run `python -m zensim.schemas.generate` after changing messages.py or
topics.py; a test fails while the files are stale. The table goes between
the `<!-- topics:begin -->` and `<!-- topics:end -->` lines of
docs/protocol.md, when run from a checkout (an installed package has no docs).
"""

from __future__ import annotations

import ast
import inspect
import json
import sys
from pathlib import Path

import msgspec

from . import messages
from .messages import WIRE_TYPES, Message
from .topics import protocol_table

SCHEMA_DIR = Path(__file__).parent / "jsonschema"
PROTOCOL_DOC = Path(__file__).resolve().parent.parent / "docs" / "protocol.md"
TABLE_BEGIN, TABLE_END = "<!-- topics:begin -->\n", "<!-- topics:end -->\n"


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


def with_protocol_table(doc: str) -> str:
    """`doc` (docs/protocol.md's text) with the table between its markers rendered anew from the topics."""
    head, rest = doc.split(TABLE_BEGIN, 1)
    _, tail = rest.split(TABLE_END, 1)
    return head + TABLE_BEGIN + protocol_table() + TABLE_END + tail


def main() -> int:
    SCHEMA_DIR.mkdir(exist_ok=True)
    for name, text in render().items():
        (SCHEMA_DIR / name).write_text(text)
        print(SCHEMA_DIR / name)
    if PROTOCOL_DOC.is_file():
        PROTOCOL_DOC.write_text(with_protocol_table(PROTOCOL_DOC.read_text()))
        print(PROTOCOL_DOC)
    return 0


if __name__ == "__main__":
    sys.exit(main())
