"""``beams.horizon``: the nearest return of a scan by bearing bin, what the tracker reads to tell
a hidden person from one who is gone."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from followbot.schemas import Array, Horizon, LaserScan, PersonCandidates, decode, encode
from followbot.services.laser_legs.beams import horizon


def scan(ranges, increment_deg=0.25, angle_min_deg=-135.0, range_max_m=30.0):
    r = np.asarray(ranges, dtype=np.float32)
    return LaserScan(
        stamp_ns=1,
        frame_id="laser",
        angle_min_rad=math.radians(angle_min_deg),
        angle_increment_rad=math.radians(increment_deg),
        range_min_m=0.05,
        range_max_m=range_max_m,
        ranges=Array.from_numpy(r),
    )


def bearing_bin(h: Horizon, deg: float) -> int:
    return int((math.radians(deg) - h.angle_min_rad) // h.increment_rad)


def test_nearest_return_per_degree_and_no_return_as_inf():
    r = np.full(1080, 5.0)  # 270 degrees at 0.25
    r[540:548] = 1.0  # 0 .. 2 degrees: something near
    r[100:120] = np.nan  # -110 .. -105: no return
    r[200:220] = 0.0
    r[300:320] = 40.0  # beyond range_max: no return
    h = horizon(scan(r))
    out = h.ranges.numpy()
    assert out.shape == (270,) and h.increment_rad == pytest.approx(math.radians(1.0))
    assert h.angle_min_rad == pytest.approx(math.radians(-135.125))
    assert out[bearing_bin(h, 0.5)] == 1.0 and out[bearing_bin(h, 1.5)] == 1.0
    assert out[bearing_bin(h, 10.0)] == 5.0
    for deg in (-107.0, -82.0, -57.0):
        assert out[bearing_bin(h, deg)] == np.inf


def test_a_descending_scan_gives_the_same_horizon_as_its_ascending_twin():
    rng = np.random.default_rng(3)
    r = rng.uniform(0.5, 8.0, 720)
    up = horizon(scan(r, increment_deg=0.375))
    down = horizon(scan(r[::-1], increment_deg=-0.375, angle_min_deg=135.0 - 0.375))
    assert down.angle_min_rad == pytest.approx(up.angle_min_rad)
    assert np.array_equal(down.ranges.numpy(), up.ranges.numpy())


def test_a_coarse_scan_keeps_its_own_resolution_and_one_beam_gets_one_bin():
    h = horizon(scan(np.full(91, 2.0), increment_deg=2.0, angle_min_deg=-90.0))
    assert h.ranges.shape == [91] and h.increment_rad == pytest.approx(math.radians(2.0))
    one = horizon(scan([3.0], increment_deg=0.0, angle_min_deg=10.0))
    assert one.ranges.numpy().tolist() == [3.0]
    assert one.angle_min_rad + one.increment_rad / 2 == pytest.approx(math.radians(10.0))


@settings(max_examples=150, deadline=None)
@given(
    st.integers(1, 3600),
    st.floats(0.05, 2.0),
    st.floats(-180.0, 180.0),
    st.booleans(),
    st.integers(0, 2**32 - 1),
)
def test_any_scan_gives_a_valid_horizon_that_travels(n, inc_deg, a0, descending, seed):
    inc_deg = min(inc_deg, 360.0 / n)
    rng = np.random.default_rng(seed)
    r = rng.uniform(-1.0, 40.0, n).astype(np.float32)
    r[rng.random(n) < 0.1] = np.nan
    r[rng.random(n) < 0.05] = np.inf
    h = horizon(scan(r, -inc_deg if descending else inc_deg, a0))
    out = h.ranges.numpy()
    assert out.shape[0] * h.increment_rad <= 2 * math.pi + 1e-6
    assert not np.isnan(out).any()
    valid = r[(r >= 0.05) & (r <= 30.0)]
    assert out.min() == (valid.min() if valid.size else np.inf)
    msg = PersonCandidates(stamp_ns=1, frame_id="laser", horizon=h)
    back = decode(PersonCandidates, encode(msg))
    assert np.array_equal(back.horizon.ranges.numpy(), out)


@pytest.mark.parametrize(
    ("ranges", "increment", "match"),
    [
        (np.zeros((2, 3), np.float32), 0.01, "1-D"),
        (np.zeros(0, np.float32), 0.01, "bins"),
        (np.zeros(400, np.float32), math.radians(1.0), "full turn"),
        (np.zeros(10, np.int32), 0.01, "float32"),
    ],
)
def test_a_malformed_horizon_is_refused(ranges, increment, match):
    with pytest.raises(ValueError, match=match):
        Horizon(angle_min_rad=0.0, increment_rad=increment, ranges=Array.from_numpy(ranges))
