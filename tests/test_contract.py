"""The wire contract: the messages stay compatible with the committed JSON Schema."""

from __future__ import annotations

import json
import subprocess
import sys

import msgspec
import pytest
from conftest import REPO

from followbot.schemas.export import CONTRACT_FILE, compatibility_problems, message_schemas
from followbot.schemas.messages import MESSAGE_TYPES


def test_messages_are_compatible_with_the_committed_contract():
    problems = compatibility_problems(json.loads(CONTRACT_FILE.read_text()), message_schemas())
    assert problems == [], (
        "the wire messages changed incompatibly; if that is deliberate, bump SCHEMA_VERSION and "
        "regenerate with `make schemas`:\n" + "\n".join(problems)
    )


def test_contract_covers_every_message():
    defs = json.loads(CONTRACT_FILE.read_text())["$defs"]
    assert {t.__name__ for t in MESSAGE_TYPES} <= set(defs)


def _doc(*types):
    _, defs = msgspec.json.schema_components(types, ref_template="#/$defs/{name}")
    return {"$defs": defs}


class Old(msgspec.Struct, tag="m", kw_only=True):
    stamp_ns: int
    x_m: float
    note: str = ""


def _variant(**fields):
    """A struct named Old (so the schemas line up) with the given annotations and defaults."""
    ns = {"__annotations__": {k: v[0] for k, v in fields.items()}}
    ns.update({k: v[1] for k, v in fields.items() if len(v) > 1})
    return type("Old", (msgspec.Struct,), ns, tag="m", kw_only=True)


@pytest.mark.parametrize(
    ("new_fields", "expected"),
    [
        ({"stamp_ns": (int,), "note": (str, "")}, "x_m: field removed or renamed"),
        ({"stamp_ns": (int,), "x": (float,), "note": (str, "")}, "x_m: field removed"),
        ({"stamp_ns": (int,), "x_m": (str,), "note": (str, "")}, "x_m: schema changed"),
        (
            {"stamp_ns": (int,), "x_m": (float,), "note": (str, ""), "y_m": (float,)},
            "y_m: new required field",
        ),
    ],
)
def test_incompatible_changes_are_caught(new_fields, expected):
    problems = compatibility_problems(_doc(Old), _doc(_variant(**new_fields)))
    assert any(expected in p for p in problems), problems


def test_a_new_optional_field_is_compatible():
    new = _variant(stamp_ns=(int,), x_m=(float,), note=(str, ""), y_m=(float, 0.0))
    assert compatibility_problems(_doc(Old), _doc(new)) == []


def test_cli_prints_and_checks_the_schemas(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "schemas"], capture_output=True, text=True, check=True
    )
    doc = json.loads(out.stdout)
    assert doc["topics"]["sensors/scan"] == "LaserScan"
    assert "LaserScan" in doc["$defs"]
    check = subprocess.run(
        [sys.executable, "-m", "followbot", "schemas", "--check"], capture_output=True, text=True
    )
    assert check.returncode == 0, check.stdout
    subprocess.run(
        [sys.executable, "-m", "followbot", "schemas", "--output", str(tmp_path)], check=True
    )
    assert json.loads((tmp_path / "messages.schema.json").read_text())["$defs"] == doc["$defs"]


def test_docs_messages_md_is_generated_from_the_current_schemas():
    from followbot.schemas.docgen import messages_markdown

    doc = REPO / "docs" / "messages.md"
    assert doc.read_text() == messages_markdown(), (
        "docs/messages.md is stale: regenerate it with `make schemas`"
    )
    for t in MESSAGE_TYPES:
        assert f"### {t.__name__}" in doc.read_text()
