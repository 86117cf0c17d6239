"""docs/settings.md is generated from the settings classes: it must match them, and every
setting a user can write must say what it means."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from followbot import settingsdoc

DOC = Path(__file__).resolve().parent.parent / "docs" / "settings.md"


def test_settings_reference_is_current():
    assert DOC.read_text() == settingsdoc.settings_markdown(), (
        "docs/settings.md is stale: regenerate it with `make schemas`"
    )


def test_every_setting_has_a_description():
    missing = settingsdoc.undocumented()
    assert not missing, "settings without a docstring:\n" + "\n".join(missing)


def test_every_service_and_plugin_is_in_the_reference():
    text = settingsdoc.settings_markdown()
    for name in settingsdoc.service_settings():
        assert f"\n## {name}\n" in text
    for role, plugins in settingsdoc.plugin_roles().items():
        for plugin in plugins:
            assert f": {plugin}\n" in text, (role, plugin)


# at module level: msgspec resolves the (string) annotations in the module's namespace
class _Inner(msgspec.Struct, kw_only=True):
    gate_m: float = 0.35
    """How far a candidate may be."""


class _Outer(msgspec.Struct, kw_only=True):
    # A comment above is a description too.
    name: str = "x"
    inner: _Inner = msgspec.field(default_factory=_Inner)


def test_nested_settings_are_listed_with_their_dotted_key():
    rows = {s.key: s for s in settingsdoc.walk(_Outer)}
    assert set(rows) == {"name", "inner.gate_m"}
    assert rows["inner.gate_m"].default == "0.35"
    assert rows["inner.gate_m"].doc == "How far a candidate may be."
    assert rows["name"].doc == "A comment above is a description too."


@pytest.mark.parametrize("service", ["tracker", "controller"])
def test_flat_core_settings_take_their_descriptions_from_the_core_class(service):
    # tracker and controller settings are built from their core class at import time
    cls = settingsdoc.service_settings()[service]
    documented = [s for s in settingsdoc.walk(cls) if s.doc]
    assert len(documented) > 10
