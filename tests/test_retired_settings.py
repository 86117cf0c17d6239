"""Removed and renamed settings: a settings file or --set naming one is told what to do."""

from __future__ import annotations

from typing import ClassVar

import msgspec
import pytest

from followbot.services.runtime.settings import (
    NodeSettings,
    SettingsError,
    load_settings,
    removed,
    renamed,
    with_node_settings,
)


class _Search(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    dwell_s: float = 1.0


class RetiringSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = {
        "old_gate_m": removed("measured and left off"),
        "look_dwell_s": renamed("search.dwell_s"),
        "search.turn_rate": removed("the camera reports its own rate"),
    }
    search: _Search = msgspec.field(default_factory=_Search)


@pytest.mark.parametrize(
    ("text", "overrides", "message"),
    [
        ("old_gate_m: 0.3\n", [], "old_gate_m was removed (measured and left off)"),
        ("", ["look_dwell_s=2"], "look_dwell_s was renamed: set search.dwell_s instead"),
        ("search: {turn_rate: 90}\n", [], "search.turn_rate was removed"),
        ("", ["search.turn_rate=90"], "search.turn_rate was removed"),
    ],
)
def test_a_removed_or_renamed_setting_is_named_with_what_to_do(tmp_path, text, overrides, message):
    """A settings file or --set naming a retired key fails with the type's own message (and
    where it came from), not msgspec's bare unknown-field error."""
    f = tmp_path / "s.yaml"
    f.write_text(text)
    with pytest.raises(SettingsError) as err:
        load_settings(RetiringSettings, f, overrides)
    assert message in str(err.value)
    assert str(err.value).startswith(f"{f}:" if text else "--set:")


def test_retired_keys_leave_other_keys_and_unknown_ones_as_before():
    s = load_settings(RetiringSettings, None, ["search.dwell_s=2"])
    assert s.search.dwell_s == 2.0
    with pytest.raises(SettingsError, match="unknown field `nope`"):
        load_settings(RetiringSettings, None, ["nope=1"])


def test_a_service_built_on_a_core_type_keeps_its_retired_settings():
    class Core(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
        retired_settings: ClassVar[dict[str, str]] = {"old": renamed("new")}
        new: int = 0

    node_type = with_node_settings(Core, "CoreNodeSettings", __name__)
    with pytest.raises(SettingsError, match="old was renamed: set new instead"):
        load_settings(node_type, None, ["old=1"])
