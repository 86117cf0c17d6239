"""Property tests over every detector: random and adversarial scans never raise, never give
NaN positions, and every reported leg lies on valid beams of its own scan, near those beams."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from followbot.schemas import LaserScan, PersonCandidates, decode, encode
from followbot.services.common.scan import valid_mask
from followbot.services.laser_legs import DETECTORS, make_detector
from followbot.services.laser_legs.scene import make_scan, person_legs

NAMES = sorted(DETECTORS)
SPECIAL = [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e-9, 1e30, 5e11]


def check(scan: LaserScan, result: PersonCandidates) -> None:
    """The invariants every detector's output obeys."""
    assert decode(PersonCandidates, encode(result)) == result  # wire constraints hold
    n = scan.ranges.shape[0]
    assert result.n_beams == n
    r = scan.ranges_m().astype(np.float64)
    valid = valid_mask(r, scan.range_min_m, scan.range_max_m)
    ang = scan.angles_rad()
    for c in result.candidates:
        for v in (c.x_m, c.y_m, c.range_m, c.bearing_rad, c.width_m, c.confidence):
            assert math.isfinite(v)
        assert 1 <= len(c.legs) <= 2
        for leg in c.legs:
            assert 0 <= leg.first_beam <= leg.last_beam < n
            span = slice(leg.first_beam, leg.last_beam + 1)
            # a detector may bridge a few beams without return inside a leg (learned's
            # dropout_beams); its end beams return
            assert valid[leg.first_beam] and valid[leg.last_beam], "a leg ends on no return"
            if result.detector != "learned":
                assert valid[span].all(), "a leg spans a beam without return"
            span = np.flatnonzero(valid[span]) + leg.first_beam
            x = r[span] * np.cos(ang[span])
            y = r[span] * np.sin(ang[span])
            tol = 1e-6 * max(1.0, float(np.max(np.abs(r[span]))))
            # a detector may move a leg from its visible surface towards its centre, behind the
            # beams, by at most half its width (thesis: leg_centre_factor * W = pi/8 W)
            tol += 0.5 * leg.width_m
            # the leg lies among its beams: inside their bounding box
            assert x.min() - tol <= leg.x_m <= x.max() + tol
            assert y.min() - tol <= leg.y_m <= y.max() + tol


HALF_DEG = math.radians(0.5)


def scan_of(ranges, *, inc=HALF_DEG, a0=None, rmin=0.02, rmax=30.0) -> LaserScan:
    ranges = np.asarray(ranges, dtype=np.float32)
    n = ranges.shape[0]
    a0 = -inc * (n - 1) / 2 if a0 is None else a0
    return LaserScan.from_ranges(
        ranges,
        stamp_ns=1,
        angle_min_rad=a0,
        angle_increment_rad=inc,
        range_min_m=rmin,
        range_max_m=rmax,
    )


ranges_st = st.lists(
    st.one_of(
        st.floats(0.0, 40.0, width=32),
        st.sampled_from(SPECIAL),
        st.floats(allow_nan=True, allow_infinity=True, width=32),
    ),
    min_size=1,
    max_size=800,
)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    ranges=ranges_st,
    inc_deg=st.sampled_from([0.25, 0.33, 0.5, 1.0, -0.5]),
    rmin=st.sampled_from([0.0, 0.02, 0.5]),
    rmax=st.sampled_from([3.0, 30.0, 1e12]),
    pred=st.one_of(st.none(), st.tuples(st.floats(-5, 5), st.floats(-5, 5))),
)
def test_random_scans(name, ranges, inc_deg, rmin, rmax, pred):
    n = len(ranges)
    inc = math.radians(inc_deg)
    if abs(inc) * (n - 1) > 2 * math.pi:
        inc = math.copysign(2 * math.pi / n, inc)
    scan = scan_of(ranges, inc=inc, rmin=rmin, rmax=rmax)
    check(scan, make_detector(name).detect(scan, prediction=pred))


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=80, deadline=None)
@given(
    px=st.floats(0.3, 6.0),
    py=st.floats(-3.0, 3.0),
    sep=st.floats(0.0, 0.6),
    noise=st.sampled_from([0.0, 0.005, 0.02]),
    drop=st.floats(0.0, 0.3),
    seed=st.integers(0, 2**32 - 1),
)
def test_noisy_scenes_with_holes(name, px, py, sep, noise, drop, seed):
    rng = np.random.default_rng(seed)
    scan = make_scan(
        person_legs(px, py, separation_m=sep),
        [(4.0, -4.0, 4.0, 4.0), (-1.0, 2.5, 4.0, 2.5)],
        fov_rad=math.radians(270),
        noise_m=noise,
        rng=rng,
    )
    r = scan.ranges_m().copy()
    holes = rng.random(r.shape[0]) < drop
    r[holes] = rng.choice(np.array(SPECIAL, dtype=np.float32), int(holes.sum()))
    scan = scan_of(r, inc=scan.angle_increment_rad, a0=scan.angle_min_rad)
    check(scan, make_detector(name).detect(scan))


ADVERSARIAL = {
    "single_beam": [1.0],
    "single_nan": [math.nan],
    "all_nan": [math.nan] * 720,
    "all_inf": [math.inf] * 720,
    "all_zero": [0.0] * 720,
    "all_negative": [-1.0] * 720,
    "all_equal": [1.5] * 720,
    "huge": [1e30] * 720,
    "alternating": [1.0, math.nan] * 360,
    "sawtooth": list(np.tile([1.0, 1.05, 1.02], 240)),
    "spikes": list(np.where(np.arange(720) % 7 == 0, 0.5, 2.0)),
    "max_beams": list(np.full(10_000, 2.0)),
}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("case", sorted(ADVERSARIAL))
def test_adversarial_scans(name, case):
    ranges = ADVERSARIAL[case]
    n = len(ranges)
    inc = min(math.radians(0.5), 2 * math.pi / n)
    scan = scan_of(ranges, inc=inc, rmax=1e12 if case == "huge" else 30.0)
    check(scan, make_detector(name).detect(scan))
    check(scan, make_detector(name).detect(scan, prediction=(math.inf, math.nan)))


@pytest.mark.parametrize("name", NAMES)
def test_full_circle_wraps_nothing(name):
    # 360 deg scan: a leg split across the first and last beam is not merged (no wrap-around),
    # but nothing breaks
    scan = make_scan(
        person_legs(-1.5, 0.0),
        [(3, -3, 3, 3)],
        fov_rad=math.radians(359.5),
        angle_min_rad=-math.pi,
    )
    check(scan, make_detector(name).detect(scan))
