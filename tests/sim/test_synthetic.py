"""The synthetic publisher's scene: its vectorised ray cast against a beam-by-beam reference."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from followbot.schemas import LaserScan, decode
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
