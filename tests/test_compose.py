"""Compose files and `followbot up`: validation, supervision, restart, clean stop."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO

from followbot.services.runtime.compose import (
    ComposeError,
    check_services,
    group_settings,
    load_compose,
    process_groups,
    service_settings,
)


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("services: {}\n", "services: Expected `object` of length >= 1"),
        ("servics: {a: {}}\n", "unknown field `servics`"),
        ("services: {a: {restart: sometimes}}\n", "services.a.restart"),
        ("services: {a: {hots: x}}\n", "unknown field `hots`"),
        ("preset: tesis\nservices: {a: {}}\n", "preset"),
        ("hosts: {robot: {}}\nservices: {a: {host: robt}}\n", "unknown host 'robt'"),
        ("robot: 'a b'\nservices: {a: {}}\n", "robot"),
        ("- just\n- a list\n", "expected a mapping"),
        ("services: [\n", "not valid YAML"),
        ("services: {a: {process: p}, b: {process: p, restart: never}}\n", "one restart"),
        (
            "hosts: {x: {}, y: {}}\n"
            "services: {a: {process: p, host: x}, b: {process: p, host: y}}\n",
            "one host",
        ),
        ("services: {a: {process: p}, b: {process: p, service: a}}\n", "each service once"),
        ("services: {a: {process: b}, b: {}}\n", "name of another service"),
    ],
)
def test_bad_compose_files_name_the_field(tmp_path, text, message):
    with pytest.raises(ComposeError, match=re.escape(message)):
        load_compose(write(tmp_path, text))


def test_settings_merge_preset_zenoh_host_and_service(tmp_path):
    c = load_compose(write(tmp_path, """
robot: r9
preset: thesis
zenoh: {mode: peer, lease_ms: 2000}
hosts:
  offboard: {zenoh: {connect: [tcp/10.0.0.1:7447]}}
services:
  laser_legs: {settings: {detector: arc}}
  vision_verify: {host: offboard, settings: {zenoh: {lease_ms: 3000}}}
"""))  # fmt: skip
    legs = service_settings(c, "laser_legs")
    assert legs["robot"] == "r9" and legs["detector"] == "arc"  # the service's own wins
    assert legs["zenoh"] == {"mode": "peer", "lease_ms": 2000}
    vision = service_settings(c, "vision_verify")
    assert vision["verifier"] == "histogram"  # from the preset
    assert vision["zenoh"] == {"mode": "peer", "lease_ms": 3000, "connect": ["tcp/10.0.0.1:7447"]}


def test_no_preset_runs_the_followbot_defaults_and_thesis_is_the_thesis(tmp_path):
    """The defaults (no preset, or ``followbot``) are the real-data choice: the learned
    detector and people confirmed on evidence; ``thesis`` keeps the thesis's parts."""
    for preset in ("", "preset: followbot\n"):
        c = load_compose(write(tmp_path, preset + "services: {laser_legs: {}, tracker: {}}\n"))
        assert service_settings(c, "laser_legs")["detector"] == "learned"
        assert service_settings(c, "tracker")["initiator"] == "evidence"
    c = load_compose(write(tmp_path, "preset: thesis\nservices: {laser_legs: {}, tracker: {}}\n"))
    assert service_settings(c, "laser_legs")["detector"] == "thesis"
    tracker = service_settings(c, "tracker")
    assert "initiator" not in tracker  # the settings' own default, the thesis's ``hits``
    from followbot.services.tracker.settings import TrackerSettings

    assert TrackerSettings().initiator == "hits"


def test_unknown_services_are_refused_with_the_installed_list(tmp_path):
    c = load_compose(write(tmp_path, "services: {tracker2: {}}\n"))
    with pytest.raises(ComposeError, match="unknown service 'tracker2'; installed: a, b"):
        check_services(c, ["a", "b"])


def test_shipped_compose_files_are_valid(tmp_path):
    from followbot.certs import main as certs

    # split_secure.yaml needs the certificates `followbot certs` makes
    assert (
        certs([str(tmp_path / "certs"), "--compose", str(REPO / "compose/split_secure.yaml")]) == 0
    )
    env = dict(os.environ, FOLLOWBOT_CERTS=str(tmp_path / "certs"))
    for path in sorted((REPO / "compose").glob("*.yaml")):
        out = subprocess.run(
            [sys.executable, "-m", "followbot", "up", str(path), "--check"],
            capture_output=True, text=True, timeout=120, env=env,
        )  # fmt: skip
        assert out.returncode == 0, f"{path.name}: {out.stderr}"


def test_bad_settings_of_a_service_stop_up_before_anything_starts(tmp_path):
    path = write(tmp_path, "services: {monitor: {settings: {topicz: [a]}}}\n")
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "up", str(path), "--log-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2
    assert "services.monitor" in out.stderr and "topicz" in out.stderr


class Up:
    def __init__(self, compose: Path, log_dir: Path, *extra: str) -> None:
        self.lines: list[str] = []
        self.p = subprocess.Popen(
            [sys.executable, "-m", "followbot", "up", str(compose), "--log-dir", str(log_dir),
             *extra],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip

    def close(self) -> None:
        self.p.kill()
        self.p.wait()
        self.p.stdout.close()

    def interrupt(self) -> str:
        """Ctrl-C: `up` must stop everything and exit 0; returns what it printed after."""
        self.p.send_signal(signal.SIGINT)
        assert self.p.wait(15) == 0
        return self.p.stdout.read()

    def expect(self, pattern: str, timeout: float = 20) -> re.Match:
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern)
        for line in self.p.stdout:
            self.lines.append(line)
            m = rx.search(line)
            if m:
                return m
            if time.monotonic() > deadline:
                break
        raise AssertionError(f"{pattern!r} not seen:\n{''.join(self.lines)}")


@pytest.mark.multiprocess
def test_up_supervises_restarts_and_stops_cleanly(tmp_path, endpoint, robot):
    compose = write(tmp_path, f"""
robot: {robot}
hosts:
  a: {{zenoh: {{listen: ["{endpoint}"]}}}}
  b: {{zenoh: {{connect: ["{endpoint}"]}}}}
services:
  monitor: {{host: a, settings: {{report_period_s: 0.3}}}}
  synthetic: {{host: b, settings: {{scan_rate_hz: 50}}}}
""")  # fmt: skip
    up = Up(compose, tmp_path / "logs")
    try:
        pid = int(up.expect(r"started monitor \(pid (\d+)\)").group(1))
        up.expect(r"^monitor\s+\| .*sensors/scan: \d+ received, [1-9]")
        # a crash is restarted with backoff
        subprocess.run(["kill", "-9", str(pid)], check=True)
        up.expect(r"monitor exited -9; restarting in 1 s")
        up.expect(r"started monitor \(pid (\d+)\)")
        up.expect(r"^monitor\s+\| .*sensors/scan: \d+ received, [1-9]")
        rest = up.interrupt()
        assert "monitor stopped" in rest and "synthetic stopped" in rest
        assert (tmp_path / "logs" / "monitor.log").read_text().count("monitor up") == 2
    finally:
        up.close()


@pytest.mark.multiprocess
def test_up_host_starts_only_that_hosts_services(tmp_path, robot):
    compose = write(tmp_path, f"""
robot: {robot}
hosts: {{a: {{}}, b: {{}}}}
services:
  monitor: {{host: a}}
  synthetic: {{host: b, settings: {{count: 20, scan_rate_hz: 200}}, stop_all_on_exit: true}}
""")  # fmt: skip
    up = Up(compose, tmp_path / "logs", "--host", "b")
    try:
        up.expect(r"started synthetic")
        up.expect(r"synthetic finished; stopping everything")
        assert up.p.wait(15) == 0
        assert not any("started monitor" in line for line in up.lines)
    finally:
        up.close()
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "up", str(compose), "--host", "c"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2 and "hosts: a, b" in out.stderr


def test_environment_variables_fill_compose_files(tmp_path, monkeypatch):
    path = write(tmp_path, "robot: ${FB_ROBOT:-r1}\nservices:\n  monitor:\n    settings:\n"
                           "      zenoh: {connect: ['tcp/${FB_HOST}:7447']}\n")  # fmt: skip
    monkeypatch.setenv("FB_HOST", "127.0.0.1")
    c = load_compose(path)
    assert c.robot == "r1"
    assert service_settings(c, "monitor")["zenoh"]["connect"] == ["tcp/127.0.0.1:7447"]
    monkeypatch.setenv("FB_ROBOT", "r2")
    assert load_compose(path).robot == "r2"
    monkeypatch.delenv("FB_HOST")
    with pytest.raises(ComposeError, match=r"\$\{FB_HOST\} is not set"):
        load_compose(path)


def test_services_of_one_process_share_its_settings_file(tmp_path):
    compose = load_compose(write(tmp_path, """
robot: r
preset: thesis
zenoh: {connect: [tcp/10.0.0.1:7447]}
services:
  laser_legs: {process: core, settings: {use_target_prediction: false}}
  vision_verify: {}
  tracker: {process: core}
  controller: {process: core}
"""))  # fmt: skip
    names = list(compose.services)
    assert process_groups(compose, names) == [
        ("core", ["laser_legs", "tracker", "controller"]),
        ("vision_verify", ["vision_verify"]),
    ]
    assert group_settings(compose, ["laser_legs", "tracker", "controller"]) == {
        "robot": "r",
        "zenoh": {"connect": ["tcp/10.0.0.1:7447"]},
        "laser_legs": {"detector": "thesis", "use_target_prediction": False},
        "tracker": {"estimator": "particle"},
        "controller": {},
    }
    bad = load_compose(write(tmp_path, """
services:
  tracker: {process: core, settings: {zenoh: {mode: client}}}
  controller: {process: core}
"""))  # fmt: skip
    with pytest.raises(ComposeError, match="same zenoh settings"):
        group_settings(bad, ["tracker", "controller"])


@pytest.mark.multiprocess
def test_up_runs_services_that_share_a_process_as_one(tmp_path, robot):
    """synthetic and monitor in one process: the monitor counts the synthetic scans it gets
    in-process; SIGINT stops both."""
    compose = write(tmp_path, f"""
robot: {robot}
services:
  synthetic: {{process: both, settings: {{scan_rate_hz: 50}}}}
  monitor: {{process: both, settings: {{report_period_s: 0.3}}}}
""")  # fmt: skip
    up = Up(compose, tmp_path / "logs")
    try:
        up.expect(r"followbot up: .*both \(synthetic\+monitor\)")
        up.expect(r"started both \(pid \d+\)")
        up.expect(r"^both\s+\| .*sensors/scan: \d+ received, [1-9]")
        rest = up.interrupt()
        assert "monitor stopped" in rest and "synthetic stopped" in rest
    finally:
        up.close()


def test_no_compose_file_listens_on_every_interface():
    for path in sorted((REPO / "compose").glob("*.yaml")):
        text = path.read_text()
        assert "0.0.0.0" not in text and "[::]" not in text, path


def test_preset_zhuang_runs_the_camera_stages_and_needs_the_targets_colour(tmp_path):
    """Seed 001's preset: camera_blobs, the hybrid estimator and the seed's rule; a file that
    names no colour to follow is refused before anything starts, saying what to write."""
    text = "preset: zhuang\nservices:\n  camera_blobs: {}\n  tracker: {}\n  controller: {}\n"
    c = load_compose(write(tmp_path, text))
    assert service_settings(c, "tracker")["estimator"] == "hybrid"
    assert service_settings(c, "controller")["rule"] == "zhuang"
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "up", str(write(tmp_path, text)), "--check"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2
    assert "camera_blobs" in out.stderr and "learn_rect" in out.stderr
