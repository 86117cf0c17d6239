"""Settings files and overrides: strict, with errors that name the key."""

from __future__ import annotations

import json

import msgspec
import pytest

from followbot.services.runtime.session import zenoh_config
from followbot.services.runtime.settings import (
    NodeSettings,
    SettingsError,
    ZenohSettings,
    apply_overrides,
    load_settings,
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
    assert s.zenoh.mode == "router" and s.zenoh.listen == ["tcp/127.0.0.1:7447"]
    assert s.zenoh.connect == ["tcp/10.0.0.2:7447"]
    f = tmp_path / "r.yaml"
    f.write_text("zenoh:\n  lease_ms: 2000\n")
    assert load_settings(RouterSettings, f).zenoh.mode == "router"


def _listen(zenoh: ZenohSettings) -> list[str]:
    return json.loads(zenoh_config(zenoh).get_json("listen/endpoints"))


def test_a_process_told_nothing_about_listening_listens_on_loopback_not_every_interface(
    tmp_path,
):
    from followbot.services.runtime.router import RouterSettings

    # zenoh's own defaults are tcp/[::]:0 (peer) and tcp/[::]:7447 (router): every interface
    assert _listen(ZenohSettings(connect=["tcp/127.0.0.1:7447"])) == ["tcp/127.0.0.1:0"]
    assert _listen(ZenohSettings(mode="router")) == ["tcp/127.0.0.1:7447"]
    assert _listen(load_settings(RouterSettings).zenoh) == ["tcp/127.0.0.1:7447"]
    # a zenoh config file that says where to listen is obeyed
    f = tmp_path / "z.json5"
    f.write_text('{ listen: { endpoints: ["tcp/127.0.0.2:0"] } }')
    assert _listen(ZenohSettings(connect=["tcp/127.0.0.1:7447"], config=str(f))) == [
        "tcp/127.0.0.2:0"
    ]


def test_the_word_off_is_a_word_and_only_true_false_are_booleans(tmp_path):
    """YAML 1.1 (PyYAML) reads off/on/yes/no as booleans: `--set learn.source=off` arrived as
    False and was refused as "expected str, got bool". Settings read YAML 1.2's booleans."""
    data = apply_overrides({}, ["learn.source=off", "a=on", "b=yes", "c=true", "d=False"])
    assert data == {"learn": {"source": "off"}, "a": "on", "b": "yes", "c": True, "d": False}
    path = tmp_path / "s.yaml"
    path.write_text("learn: {source: off}\nverifier: online\n")
    from followbot.services.vision_verify.settings import VisionVerifySettings

    assert load_settings(VisionVerifySettings, path).learn.source == "off"
