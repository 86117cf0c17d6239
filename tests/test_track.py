"""followbot track: a real recording through the real pipeline, deterministically."""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest
from conftest import SHARED_DATA

DEMO_BAG = SHARED_DATA / "leg_tracker" / "demo_stationary_simple_environment.bag"
pytestmark = [
    pytest.mark.multiprocess,
    pytest.mark.skipif(not DEMO_BAG.is_file(), reason=f"leg_tracker data absent at {DEMO_BAG}"),
]


def track(out, *extra):
    return subprocess.run(
        [sys.executable, "-m", "followbot", "track", str(DEMO_BAG), "--scan-topic", "/scan",
         "--output", str(out), "--max-scans", "250", *extra],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip


def rows(path):
    with path.open() as f:
        return list(csv.reader(f))


def test_a_ros1_bag_is_tracked_end_to_end_and_deterministically(tmp_path):
    a, b = track(tmp_path / "a"), track(tmp_path / "b")
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    assert "tracked 250 scans" in a.stdout
    people, target = rows(tmp_path / "a" / "people.csv"), rows(tmp_path / "a" / "target.csv")
    assert people[0] == ["stamp_ns", "id", "x_m", "y_m", "vx_mps", "vy_mps"]
    assert len(people) > 100 and len(target) > 20  # people walk round the still robot
    stamps = [int(r[0]) for r in target[1:]]
    assert stamps == sorted(stamps)
    assert all(abs(float(r[2])) < 30 and abs(float(r[3])) < 30 for r in people[1:])
    # the same recording gives the same tracks
    assert rows(tmp_path / "b" / "people.csv") == people
    assert rows(tmp_path / "b" / "target.csv") == target
    assert (tmp_path / "a" / "tracks.mcap").stat().st_size > 10_000


def test_missing_topics_and_bad_settings_are_clear_errors(tmp_path):
    out = track(tmp_path, "--odom-topic", "/odom")
    assert out.returncode == 2 and "no topic ['/odom']" in out.stderr
    out = track(tmp_path, "--set", "nope.detector=x")
    assert out.returncode == 2 and "SERVICE.KEY=VALUE" in out.stderr
