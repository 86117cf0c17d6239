"""The followbot command as a user meets it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.multiprocess


def followbot(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "followbot", *args], capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def test_help_lists_the_commands():
    out = followbot("--help")
    assert out.returncode == 0
    for cmd in ("run", "services", "topics", "schemas", "demo", "smoke", "bench", "eval", "up",
                "appearance", "status"):  # fmt: skip
        assert cmd in out.stdout


def test_service_help_shows_its_settings():
    out = followbot("run", "synthetic", "--help")
    assert out.returncode == 0
    assert "scan_rate_hz: 40.0" in out.stdout and "--connect" in out.stdout


def test_unknown_service_lists_the_valid_ones():
    out = followbot("run", "nope")
    assert out.returncode == 2
    assert "unknown service 'nope'; valid names:" in out.stderr and "synthetic" in out.stderr


def test_bad_settings_key_is_named(tmp_path):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("scan_rate_hz: 10\nbeamz: 5\n")
    out = followbot("run", "synthetic", "--config", str(cfg))
    assert out.returncode == 2
    assert "unknown field `beamz`" in out.stderr and str(cfg) in out.stderr


def test_a_removed_tracker_setting_is_named_as_removed(tmp_path):
    """A settings file kept from an older version, naming an experiment that was taken out,
    stops the service before it starts, with the key and why."""
    cfg = tmp_path / "tracker.yaml"
    cfg.write_text("max_misses: 8\nocclusion_max_s: 3.0\n")
    out = followbot("run", "tracker", "--config", str(cfg), "--print-settings")
    assert out.returncode == 2
    assert f"{cfg}: occlusion_max_s was removed" in out.stderr
    assert "docs/tracker_log.md" in out.stderr


def test_print_settings_shows_file_and_overrides(tmp_path):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("scan_rate_hz: 10\n")
    out = followbot(
        "run", "synthetic", "--config", str(cfg), "--set", "beams=360", "--print-settings"
    )
    assert out.returncode == 0
    assert "scan_rate_hz: 10.0" in out.stdout and "beams: 360" in out.stdout


def test_topics_lists_every_topic():
    out = followbot("topics")
    assert "sensors/scan" in out.stdout and "LaserScan" in out.stdout


def test_smoke_runs_real_processes_and_reports_measured_figures(tmp_path):
    out = followbot("smoke", "--duration", "2", "--output", str(tmp_path), timeout=90)
    assert out.returncode == 0, out.stdout + out.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    scans = summary["topics"]["sensors/scan"]
    assert scans["received"] >= 60  # 2 s at 40 Hz
    # Sensor streams drop (never block) under congestion, so a machine loaded by other work may
    # lose the odd scan; the demo reports it honestly. More than 1 % would be a fault.
    assert scans["lost"] <= scans["received"] // 100 and scans["rejected"] == 0
    assert summary["exit_codes"] == {"monitor": 0, "synthetic": 0}
    assert "sensors/scan" in out.stdout and "OK" in out.stdout


def _service_names() -> list[str]:
    from followbot.services.runtime.plugins import Registry

    return Registry("services").names()


@pytest.mark.parametrize("name", _service_names())
def test_every_registered_service_loads_and_explains_its_settings(name):
    """Conformance over every implementation of the 'services' role."""
    out = followbot("run", name, "--help")
    assert out.returncode == 0, out.stderr
    assert f"followbot run {name}" in out.stdout
    assert "settings (defaults shown" in out.stdout and "zenoh:" in out.stdout


def test_target_command_reaches_vision_verify(spawn, endpoint, robot):
    vision = spawn("run", "vision_verify", "--robot", robot, "--listen", endpoint)
    vision.wait_for_output("vision_verify up", timeout=20)
    out = followbot("target", "reset", "--robot", robot, "--connect", endpoint, "--wait", "10")
    assert out.returncode == 0, out.stderr
    assert "sent reset" in out.stdout
    assert "vision_verify: done: target model dropped" in out.stdout  # its report, read back
    vision.wait_for_output("target model dropped", timeout=10)
    nobody = followbot("target", "reset", "--robot", robot + "x", "--wait", "0.5")
    assert nobody.returncode == 1 and "no vision_verify listening" in nobody.stderr


def test_demo_follows_the_right_person_and_writes_its_outputs(tmp_path):
    """make demo: the whole system in the simulator; figures, report, plots, recording."""
    out = followbot("demo", "--output", str(tmp_path), timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "followed the right person:" in out.stdout
    summary = json.loads((tmp_path / "summary.json").read_text())
    m = summary["scenarios"]["thesis_5_2_4_two_people"]
    assert m["tracked_visible_share"] > 0.8 and m["rmse_m"] < 0.2
    assert m["identity_switches"] <= 1 and m["wrong_target_s"] < 1.0
    assert (tmp_path / "report.md").is_file()
    assert len(list((tmp_path / "plots").glob("*.png"))) == 3
    assert (tmp_path / "run" / "run.mcap").stat().st_size > 10_000
