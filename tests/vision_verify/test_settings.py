"""vision_verify's settings nested by role: a settings file or --set written for the flat
names is told the key to use now, or why the setting is gone; the nested keys take values."""

from __future__ import annotations

import json
import subprocess
import sys

import msgspec
import pytest

from followbot.services.runtime.settings import SettingsError, load_settings
from followbot.services.vision_verify.settings import VisionVerifySettings

# NodeSettings' own fields are common to every service and not counted against the limit
_COMMON = {"robot", "zenoh", "health_period_s", "clock", "log_level", "laser_mount"}


def test_every_retired_setting_is_refused_with_its_own_message():
    retired = VisionVerifySettings.retired_settings
    assert retired and not set(retired) & set(VisionVerifySettings.__struct_fields__)
    defaults = msgspec.to_builtins(VisionVerifySettings())
    for key, note in retired.items():
        with pytest.raises(SettingsError) as err:
            load_settings(VisionVerifySettings, None, [f"{key}=1"])
        assert str(err.value) == f"--set: {key} {note}"
        if "renamed" in note:  # the new key exists and takes its default back
            new = note.split("set ")[1].split()[0]
            section, name = new.split(".")
            value = defaults[section][name]
            loaded = load_settings(VisionVerifySettings, None, [f"{new}={json.dumps(value)}"])
            assert msgspec.to_builtins(getattr(loaded, section))[name] == value


def test_nested_settings_come_from_a_file_section_or_a_dotted_key(tmp_path):
    cfg = tmp_path / "vision.yaml"
    cfg.write_text("acquire: {auto: true}\nocclusion: {laser_margin_m: null}\n")
    s = load_settings(VisionVerifySettings, cfg, ["learn.source=confident"])
    assert s.acquire.auto and s.occlusion.laser_margin_m is None
    assert s.learn.source == "confident"
    assert s.occlusion.min_visible_fraction == 0.5  # the section's other defaults stay
    assert s.acquire.diff_threshold == 80.0


def test_at_most_25_top_level_settings():
    own = set(VisionVerifySettings.__struct_fields__) - _COMMON
    assert len(own) <= 25, sorted(own)


def test_an_old_settings_file_stops_the_service_with_the_new_key(tmp_path):
    """A real `followbot run vision_verify` given a file with a flat key refuses to start
    (exit 2), naming the key and its replacement."""
    cfg = tmp_path / "vision.yaml"
    cfg.write_text("verifier: histogram\nauto_acquire: true\n")
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "run", "vision_verify", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert f"{cfg}: auto_acquire was renamed: set acquire.auto instead" in out.stderr
