"""The synthetic publisher's scene: its vectorised ray cast against a beam-by-beam reference."""

from __future__ import annotations

import math
import threading
import time

import msgspec
import numpy as np
import pytest

from followbot.schemas import Keys, LaserScan, decode
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.node import Node
from followbot.services.sim.synthetic import SyntheticScene, SyntheticSettings, setup


def _reference(scene: SyntheticScene, t_s: float) -> list[float]:
    """Each beam on its own: the nearest leg circle in front of the laser, else the room."""
    legs = scene.legs(t_s).tolist()
    out = []
    for a in scene.angles.tolist():
        dx, dy = math.cos(a), math.sin(a)
        best = scene.s.room_radius_m
        for cx, cy in legs:
            b = dx * cx + dy * cy
            disc = b * b - (cx * cx + cy * cy - scene.LEG_RADIUS_M**2)
            if disc >= 0 and b - math.sqrt(disc) > 0:
                best = min(best, b - math.sqrt(disc))
        out.append(best if best <= scene.s.max_range_m else math.inf)
    return out


@pytest.mark.parametrize(("fov_deg", "beams"), [(100, 200), (270, 720), (360, 361)])
@pytest.mark.parametrize("walk_radius_m", [0.8, 1.5, 3.0])
def test_ranges_match_a_beam_by_beam_reference(fov_deg, beams, walk_radius_m):
    settings = msgspec.convert(
        {"fov_deg": fov_deg, "beams": beams, "noise_m": 0.0, "walk_radius_m": walk_radius_m},
        SyntheticSettings,
    )
    scene = SyntheticScene(settings)
    on_legs = 0
    for t in np.linspace(0.0, 20.0, 41):
        got = scene.ranges(float(t))
        want = np.asarray(_reference(scene, float(t)), dtype=np.float32)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
        on_legs += int((want < settings.room_radius_m - 1e-3).sum())
    assert on_legs > 20  # the walker was in view: the comparison covered leg hits


def test_publishes_count_scans_numbered_without_gaps():
    net = FakeNetwork()
    settings = msgspec.convert(
        {"scan_rate_hz": 2000, "count": 300, "odom_rate_hz": 0}, SyntheticSettings
    )
    node = Node("synthetic", settings, net.bus())
    setup(node, settings)
    node.run(duration_s=30)
    scans = [decode(LaserScan, p) for k, p in net.published if k.endswith("/sensors/scan")]
    assert [s.seq for s in scans] == list(range(300))
    assert all(len(s.ranges_m()) == 720 for s in scans)


@pytest.mark.parametrize("people", [0, 1, 3])
def test_people_walk_one_circle_evenly_spaced(people):
    settings = msgspec.convert({"people": people, "noise_m": 0.0}, SyntheticSettings)
    scene = SyntheticScene(settings)
    for t in (0.0, 3.7, 11.2):
        legs = scene.legs(t)
        assert legs.shape == (2 * people, 2)
        centres = legs.reshape(people, 2, 2).mean(axis=1)
        np.testing.assert_allclose(np.hypot(*centres.T), settings.walk_radius_m, atol=1e-9)
        bearings = np.sort(np.arctan2(centres[:, 1], centres[:, 0]))
        if people > 1:
            gaps = np.diff(np.concatenate([bearings, bearings[:1] + 2 * math.pi]))
            np.testing.assert_allclose(gaps, 2 * math.pi / people, atol=1e-9)
        np.testing.assert_allclose(scene.ranges(t), _reference(scene, t), atol=1e-6)
    if people:  # the first walker is where the single walker of earlier versions was
        one = SyntheticScene(msgspec.convert({"noise_m": 0.0}, SyntheticSettings))
        np.testing.assert_allclose(scene.legs(2.5)[:2], one.legs(2.5))


def _run_until_first_scan(net: FakeNetwork, settings: SyntheticSettings) -> float:
    """Seconds from the start of setup until the synthetic node published its first scan."""
    node = Node("synthetic", settings, net.bus())
    t0 = time.monotonic()
    setup(node, settings)
    node.run(duration_s=30)
    assert any(k.endswith("/sensors/scan") for k, _ in net.published)
    return time.monotonic() - t0


def test_waits_for_stages_before_the_first_scan():
    net = FakeNetwork()
    settings = msgspec.convert(
        {"scan_rate_hz": 1000, "count": 5, "odom_rate_hz": 0, "robot": "r1",
         "wait_for_stages": ["laser_legs", "tracker"], "start_timeout_s": 20},
        SyntheticSettings,
    )  # fmt: skip
    other = net.bus()
    other.liveliness_token(Keys("r1").alive("laser_legs"))  # one of two: not enough
    threading.Timer(0.4, lambda: other.liveliness_token(Keys("r1").alive("tracker"))).start()
    took = _run_until_first_scan(net, settings)
    assert 0.4 <= took < 10.0


def test_publishes_anyway_when_stages_do_not_come():
    net = FakeNetwork()
    settings = msgspec.convert(
        {"scan_rate_hz": 1000, "count": 5, "odom_rate_hz": 0,
         "wait_for_stages": ["laser_legs"], "start_timeout_s": 0.3},
        SyntheticSettings,
    )  # fmt: skip
    took = _run_until_first_scan(net, settings)
    assert 0.3 <= took < 10.0
    scans = [decode(LaserScan, p) for k, p in net.published if k.endswith("/sensors/scan")]
    assert [s.seq for s in scans] == list(range(5))
