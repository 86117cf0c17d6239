import math

import numpy as np
import pytest

from followbot.services.sim.laser import LaserModel, cast_rays
from followbot.services.sim.scenario import LaserSpec
from followbot.services.sim.simulation import Simulation

from .helpers import scenario, standing


def _reference(origin, angles, segments, circles, max_range):
    """One ray at a time, the textbook way: the oracle for the vectorised caster."""
    ranges, hits = [], []
    for a in angles:
        d = (math.cos(a), math.sin(a))
        best, hit = math.inf, -1
        for k, (x0, y0, x1, y1) in enumerate(segments):
            ex, ey, qx, qy = x1 - x0, y1 - y0, x0 - origin[0], y0 - origin[1]
            den = d[0] * ey - d[1] * ex
            if abs(den) < 1e-15:
                continue
            t = (qx * ey - qy * ex) / den
            u = (qx * d[1] - qy * d[0]) / den
            if t > 0 and 0 <= u <= 1 and t < best:
                best, hit = t, k
        for k, (cx, cy, r) in enumerate(circles):
            wx, wy = cx - origin[0], cy - origin[1]
            b = d[0] * wx + d[1] * wy
            disc = b * b - (wx * wx + wy * wy - r * r)
            if disc >= 0 and 0 < b - math.sqrt(disc) < best:
                best, hit = b - math.sqrt(disc), len(segments) + k
        if best > max_range:
            best, hit = math.inf, -1
        ranges.append(best)
        hits.append(hit)
    return np.array(ranges), np.array(hits)


@pytest.mark.parametrize(
    ("a0", "inc_deg", "n"),
    [(-math.pi, 0.5, 720), (2.9, 0.5, 201), (-0.3, 1.0, 270), (1.0, 0.25, 1440)],
)
def test_vectorised_caster_matches_reference(a0, inc_deg, n):
    rng = np.random.default_rng(5)
    segments = np.column_stack([rng.uniform(-6, 6, (30, 2)), rng.uniform(-6, 6, (30, 2))])
    circles = np.column_stack([rng.uniform(-6, 6, (40, 2)), rng.uniform(0.02, 0.3, 40)])
    origin = (0.2, -0.1)
    circles = circles[
        np.hypot(circles[:, 0] - origin[0], circles[:, 1] - origin[1]) > circles[:, 2]
    ]
    inc = math.radians(inc_deg)
    ranges, hits = cast_rays(origin, a0, inc, n, segments, circles, 8.0)
    want_r, want_h = _reference(origin, a0 + inc * np.arange(n), segments, circles, 8.0)
    assert np.array_equal(np.isinf(ranges), np.isinf(want_r))
    fin = np.isfinite(want_r)
    assert np.allclose(ranges[fin], want_r[fin], atol=1e-9)
    assert np.array_equal(hits, want_h)
    assert fin.sum() > n // 4  # the scene is not empty


def test_beam_layout_follows_the_spec():
    sick = LaserModel(LaserSpec())  # thesis 5.1: 100 deg at 0.5 deg
    assert sick.n_beams == 201
    assert sick.angles_rad[0] == pytest.approx(-math.radians(50))
    assert sick.angles_rad[-1] == pytest.approx(math.radians(50))
    full = LaserModel(LaserSpec(fov_deg=360.0, resolution_deg=0.5))
    assert full.n_beams == 720


def test_person_appears_as_two_leg_arcs_at_the_right_range_and_bearing():
    noise = 0.015  # thesis 5.1: 15 mm
    sim = Simulation(
        scenario(people=[standing(1, 2.0, 0.5)], laser={"range_noise_m": noise}), seed=3
    )
    scan = sim.scan()
    truth = sim.truth()
    ranges = scan.ranges_m().astype(float)
    angles = scan.angles_rad()
    legs = np.array(truth.people[0].legs_robot_m).reshape(2, 2)
    radius = sim.people[0].leg_radius_m
    assert truth.people[0].visible_laser
    for leg in legs:
        d, bearing = float(np.hypot(*leg)), math.atan2(leg[1], leg[0])
        half = math.asin(radius / d)
        on_leg = np.abs(angles - bearing) < half - 0.002
        expected_beams = 2 * half / scan.angle_increment_rad
        assert abs(on_leg.sum() - expected_beams) <= 2
        # each beam on the leg reads the exact ray/circle distance, within the noise
        dx, dy = np.cos(angles[on_leg]), np.sin(angles[on_leg])
        beta = dx * leg[0] + dy * leg[1]
        exact = beta - np.sqrt(beta**2 - (d**2 - radius**2))
        err = ranges[on_leg] - exact
        assert np.all(np.abs(err) < 5 * noise)
        assert abs(err.mean()) < 3 * noise / math.sqrt(on_leg.sum())
        assert np.std(err) == pytest.approx(noise, rel=0.6)
        # the closest point is in the middle of the arc (convex towards the robot)
        mid_bearing = angles[on_leg][np.argmin(exact)]
        assert abs(mid_bearing - bearing) <= scan.angle_increment_rad
    # nothing else in the scan: every other beam reads "no return"
    off = np.ones_like(ranges, dtype=bool)
    for leg in legs:
        b = math.atan2(leg[1], leg[0])
        off &= np.abs(angles - b) > math.asin(radius / np.hypot(*leg)) + 0.01
    assert np.all(np.isinf(ranges[off]))


def test_dropouts_and_spurious_returns():
    model = LaserModel(LaserSpec(dropout_prob=1.0))
    true = np.full(model.n_beams, 3.0)
    assert np.all(np.isnan(model.corrupt(true, np.random.default_rng(0))))
    model = LaserModel(LaserSpec(spurious_prob=1.0, range_noise_m=0.0))
    got = model.corrupt(true, np.random.default_rng(0))
    assert np.all(got <= 3.0) and got.min() < 1.0
    model = LaserModel(LaserSpec(range_noise_m=0.0))
    got = model.corrupt(np.array([np.inf, 9.0, 2.0]), np.random.default_rng(0))
    assert np.isinf(got[0]) and np.isinf(got[1]) and got[2] == pytest.approx(2.0)


def test_box_hides_the_legs_behind_it():
    sc = scenario(
        world={"boxes": [{"centre": [2.0, 0.0], "size_m": [0.4, 1.0], "height_m": 1.0}]},
        people=[standing(1, 3.5, 0.0), standing(2, 3.5, 1.5)],
    )
    truth = Simulation(sc).truth()
    assert not truth.people[0].visible_laser
    assert truth.people[1].visible_laser
