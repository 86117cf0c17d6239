"""seed 002's edge patterns (LA / FS / SL) and the learned detector's model and features."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.services.laser_legs import make_detector
from followbot.services.laser_legs.detectors.bellotto import EdgePatternDetector
from followbot.services.laser_legs.detectors.learned import (
    FEATURES,
    default_model_path,
    segment_features,
    segments,
)
from followbot.services.laser_legs.scene import make_scan, person_legs

WALL = [(3.0, -3.0, 3.0, 3.0)]
R = 0.06


def _patterns(scan):
    return sorted(c.pattern for c in EdgePatternDetector().detect(scan).candidates)


def test_legs_apart_is_LA_with_two_legs():
    scan = make_scan(person_legs(1.5, 0.0, separation_m=0.3, leg_radius_m=R), WALL)
    (c,) = EdgePatternDetector().detect(scan).candidates
    assert c.pattern == "LA" and len(c.legs) == 2
    assert math.hypot(c.x_m - 1.5, c.y_m) < 0.06
    assert all(0.10 < leg.width_m < 0.20 for leg in c.legs)


def test_single_leg_and_legs_together_are_SL():
    assert _patterns(make_scan([(1.5, 0.4, R)], WALL)) == ["SL"]
    together = person_legs(1.5, -0.4, separation_m=2 * R, leg_radius_m=R)  # touching
    assert _patterns(make_scan(together, WALL)) == ["SL"]


def test_forward_straddle_is_FS():
    # one leg 0.25 m behind the other along the line of sight, half hidden
    legs = [(1.5, 0.0, R), (1.75, 0.07, R)]
    (c,) = EdgePatternDetector().detect(make_scan(legs, WALL)).candidates
    assert c.pattern == "FS" and len(c.legs) == 2
    assert c.legs[0].last_beam < c.legs[1].first_beam or c.legs[1].last_beam < c.legs[0].first_beam


def test_thin_objects_and_walls_are_no_legs():
    table_leg = make_scan([(1.5, 0.0, 0.012)], WALL)  # 2.4 cm: removed by the max operator
    assert _patterns(table_leg) == []
    barrel = make_scan([(1.5, 0.0, 0.35)], WALL)  # 70 cm: too wide for any pattern
    assert _patterns(barrel) == []


def test_bellotto_settings_are_checked():
    with pytest.raises(ValueError):
        make_detector("bellotto", {"min_window_beams": 4})
    with pytest.raises(ValueError):
        make_detector("bellotto", {"leg_min_m": 0.3})


def test_learned_model_is_shipped_and_finds_clean_legs():
    assert default_model_path().is_file()
    legs = person_legs(1.5, 0.3, separation_m=0.3, leg_radius_m=R)
    scan = make_scan(legs, WALL, fov_rad=math.radians(180))
    result = make_detector("learned").detect(scan)
    found = [(leg.x_m, leg.y_m) for c in result.candidates for leg in c.legs]
    for lx, ly, _ in legs:
        assert min(math.hypot(x - lx, y - ly) for x, y in found) < 0.06
    assert all(0.0 <= c.confidence <= 1.0 for c in result.candidates)


def test_segment_features_are_finite_and_describe_shape():
    plank = [(2.5, 1.0, 2.5, 1.3)]  # 30 cm, flat (segments wider than 0.6 m are dropped)
    scan = make_scan([(1.5, 0.0, R), (2.0, -1.0, 0.02)], plank)
    st, en, x, y, r, valid = segments(scan)
    f = segment_features(st, en, x, y, r, valid)
    assert f.shape == (len(st), len(FEATURES)) and np.isfinite(f).all()
    col = {name: i for i, name in enumerate(FEATURES)}
    wall = int(np.argmax(f[:, col["width_m"]]))
    assert f[wall, col["width_m"]] == pytest.approx(0.3, abs=0.05)
    leg = int(np.argmin(np.abs(f[:, col["range_m"]] - 1.46)))
    assert f[leg, col["circle_radius_m"]] == pytest.approx(R, abs=0.015)
    assert f[wall, col["line_residual_m"]] < 1e-3 < f[leg, col["line_residual_m"]]
    assert f[leg, col["step_before_m"]] > 0.5 and f[leg, col["step_after_m"]] > 0.5
