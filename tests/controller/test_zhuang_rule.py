"""Seed 001's control rule: dead band on the column (scaled from 192 px), k_p turn, distance."""

from __future__ import annotations

import math

import pytest

from followbot.services.controller.zhuang import ZhuangRule, ZhuangSettings


@pytest.mark.parametrize("width", [192, 320, 640])
def test_the_dead_band_is_the_seeds_76_to_116_of_192_scaled_to_the_width(width):
    rule = ZhuangRule()
    k = width / 192
    assert rule.command(76 * k, width, 1.5)[1] == 0.0
    assert rule.command(116 * k, width, 1.5)[1] == 0.0
    assert rule.command(75 * k, width, 1.5)[1] > 0.0  # left of the band: turn left (ccw)
    assert rule.command(117 * k, width, 1.5)[1] < 0.0


def test_the_band_is_on_the_column_not_the_row_as_the_seed_prints():
    # seed 5.1 says "on the y-axis", but 76-116 is centred on 96 = 192 / 2 (144 / 2 is 72)
    lo, hi = ZhuangSettings().dead_band_px
    assert (lo + hi) / 2 == 192 / 2


def test_the_turn_is_proportional_to_the_offset_from_the_centre():
    rule = ZhuangRule(ZhuangSettings(k_p=0.01))
    w1 = rule.command(160 + 60, 320, 1.5)[1]
    w2 = rule.command(160 + 120, 320, 1.5)[1]
    assert w2 == pytest.approx(2 * w1)
    assert w1 == pytest.approx(-0.01 * 60 * 192 / 320)


def test_forward_beyond_the_maximum_distance_back_inside_the_safe_one():
    rule = ZhuangRule()
    assert rule.command(160, 320, 3.0)[0] > 0
    assert rule.command(160, 320, 2.0)[0] == 0
    assert rule.command(160, 320, 0.6)[0] < 0
    assert rule.command(160, 320, math.nan)[0] == 0  # no floor point: turn only


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="below max_distance_m"):
        ZhuangSettings(safe_distance_m=2.5, max_distance_m=2.0)
    with pytest.raises(ValueError, match="dead_band_px"):
        ZhuangSettings(dead_band_px=(120.0, 80.0))
