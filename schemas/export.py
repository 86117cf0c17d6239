"""JSON Schema of every message, and the compatibility check against a committed contract.

``schemas/contract/messages.schema.json`` is the contract: the JSON Schema of every message as
released. :func:`compatibility_problems` compares the current code against it. A field removed,
renamed or retyped, a tag changed, or a new field without a default breaks old readers or
writers and is reported; a new field with a default is compatible (msgspec's evolution rules).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgspec

from .base import SCHEMA_VERSION
from .keys import TOPICS
from .messages import MESSAGE_TYPES

__all__ = ["CONTRACT_FILE", "compatibility_problems", "message_schemas", "write_schemas"]

CONTRACT_FILE = Path(__file__).with_name("contract") / "messages.schema.json"


def message_schemas() -> dict[str, Any]:
    """One document: ``$defs`` of every struct, plus the topic -> message map."""
    _, components = msgspec.json.schema_components(MESSAGE_TYPES, ref_template="#/$defs/{name}")
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "followbot wire messages",
        "description": (
            "msgpack-encoded on the wire (arrays as bytes); JSON Schema here for documentation "
            "and contract tests. Byte fields appear as base64 strings in JSON."
        ),
        "schema_version": SCHEMA_VERSION,
        "topics": {topic: t.__name__ for topic, t in TOPICS.items()}
        | {"health/<service>": "Health"},
        "$defs": components,
    }


def write_schemas(directory: Path) -> list[Path]:
    """Write the schema document (``messages.schema.json``) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    doc = message_schemas()
    written = [directory / "messages.schema.json"]
    written[0].write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return written


def compatibility_problems(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Why ``new`` cannot read what ``old`` wrote, or old readers cannot read ``new``'s output."""
    problems: list[str] = []
    old_defs, new_defs = old.get("$defs", {}), new.get("$defs", {})
    for name, o in old_defs.items():
        n = new_defs.get(name)
        if n is None:
            problems.append(f"{name}: struct removed or renamed")
            continue
        o_props, n_props = o.get("properties", {}), n.get("properties", {})
        for field, o_schema in o_props.items():
            if field not in n_props:
                problems.append(f"{name}.{field}: field removed or renamed")
            elif _strip_doc(n_props[field]) != _strip_doc(o_schema):
                problems.append(
                    f"{name}.{field}: schema changed from {_strip_doc(o_schema)} "
                    f"to {_strip_doc(n_props[field])}"
                )
        for field in set(n.get("required", [])) - set(o.get("required", [])):
            problems.append(f"{name}.{field}: new required field (give it a default)")
    for topic, type_name in old.get("topics", {}).items():
        if new.get("topics", {}).get(topic) != type_name:
            problems.append(
                f"topic {topic}: was {type_name}, now {new.get('topics', {}).get(topic)}"
            )
    return problems


def _strip_doc(schema: Any) -> Any:
    """A schema without its prose (descriptions and titles may change freely)."""
    if isinstance(schema, dict):
        return {k: _strip_doc(v) for k, v in schema.items() if k not in ("description", "title")}
    if isinstance(schema, list):
        return [_strip_doc(v) for v in schema]
    return schema
