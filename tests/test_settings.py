"""Settings files and overrides: strict, with errors that name the key."""

from __future__ import annotations

from typing import ClassVar

import msgspec
import pytest

from followbot.services.runtime.session import zenoh_config
from followbot.services.runtime.settings import (
    NodeSettings,
    SettingsError,
    ZenohSettings,
    apply_overrides,
    load_settings,
    removed,
    renamed,
    with_node_settings,
)


class DemoSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    rate_hz: float = 10.0
    names: list[str] = []


def test_defaults_file_and_overrides_apply_in_order(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("robot: r7\nrate_hz: 20\nzenoh:\n  mode: client\n")
    s = load_settings(DemoSettings, f, ["rate_hz=40", "zenoh.connect=[tcp/10.0.0.1:7447]"])
    assert s.robot == "r7" and s.rate_hz == 40.0
    assert s.zenoh.mode == "client" and s.zenoh.connect == ["tcp/10.0.0.1:7447"]
    assert s.health_period_s == 1.0


def test_json_files_work_too(tmp_path):
    f = tmp_path / "s.json"
    f.write_text('{"names": ["a", "b"]}')
    assert load_settings(DemoSettings, f).names == ["a", "b"]


@pytest.mark.parametrize(
    ("text", "overrides", "message"),
    [
        ("rate_hzz: 3\n", [], "unknown field `rate_hzz`"),
        ("zenoh:\n  mdoe: peer\n", [], "zenoh: Object contains unknown field `mdoe`"),
        ("rate_hz: fast\n", [], "rate_hz: Expected `float`"),
        ("zenoh:\n  mode: bridge\n", [], "zenoh.mode"),
        ("zenoh:\n  lease_ms: 5\n", [], "zenoh.lease_ms"),
        ("- a\n- b\n", [], "expected a mapping"),
        ("rate_hz: [1,\n", [], "not valid YAML"),
        ("", ["rate_hz"], "key=value"),
        ("robot: r1\n", ["robot.name=x"], "not a section"),
        ("", ["robot.name=x"], "not a section"),
        ("", ["robot=a/b"], "robot name 'a/b' must be 1-64 characters"),
        ("robot: 'two words'\n", [], "robot name 'two words' must be"),
        ("clock:\n  max_ahead_s: -1\n", [], "clock.max_ahead_s"),
    ],
)
def test_bad_settings_name_the_problem(tmp_path, text, overrides, message):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(SettingsError, match=message.replace("[", r"\[")):
        load_settings(DemoSettings, f, overrides)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(SettingsError, match="cannot read settings file"):
        load_settings(DemoSettings, tmp_path / "nope.yaml")


def test_override_values_are_yaml():
    d = apply_overrides({}, ["a.b=3", "a.c=[x, y]", "d=true", "e="])
    assert d == {"a": {"b": 3, "c": ["x", "y"]}, "d": True, "e": ""}


def test_zenoh_config_defaults_and_explicit_endpoints():
    conf = zenoh_config(ZenohSettings(listen=["tcp/127.0.0.1:0"], connect=[]))
    assert conf.get_json("mode") == '"peer"'
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert conf.get_json("transport/shared_memory/enabled") == "false"
    assert conf.get_json("transport/link/tx/lease") == "1000"
    drop = "transport/link/tx/queue/congestion_control/drop/wait_before_drop"
    assert conf.get_json(drop) == "50000"  # microseconds; zenoh's own default is 1000
    assert "tcp/127.0.0.1:0" in conf.get_json("listen/endpoints")
    with pytest.raises(ValueError, match="connect/endpoints"):
        zenoh_config(ZenohSettings(connect=["not an endpoint"]))


def test_settings_help_round_trips_through_yaml():
    s = load_settings(DemoSettings)
    assert msgspec.to_builtins(s)["zenoh"]["mode"] == "peer"


def test_a_partial_section_keeps_the_other_defaults_of_that_section(tmp_path):
    from followbot.services.runtime.router import RouterSettings

    s = load_settings(RouterSettings, None, ["zenoh.connect=[tcp/10.0.0.2:7447]"])
    assert s.zenoh.mode == "router" and s.zenoh.listen == ["tcp/0.0.0.0:7447"]
    assert s.zenoh.connect == ["tcp/10.0.0.2:7447"]
    f = tmp_path / "r.yaml"
    f.write_text("zenoh:\n  lease_ms: 2000\n")
    assert load_settings(RouterSettings, f).zenoh.mode == "router"


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
