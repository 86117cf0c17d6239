"""Seed 001's control rule: dead band on the column (scaled from 192 px), k_p turn, distance."""

from __future__ import annotations

import math

import msgspec
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


# --------------------------------------------------------------------------- as a controller rule


def _target(x, y, status="tracking", **kw):
    from followbot.schemas import TrackState

    return TrackState(stamp_ns=1, frame_id="base_link", status=status, x_m=x, y_m=y, **kw)


def _controller(**kw):
    from followbot.services.controller.core import ControllerSettings, FollowController

    return FollowController(
        msgspec.convert({"rule": "zhuang", "guard": {"enabled": False}, **kw}, ControllerSettings)
    )


def test_rule_zhuang_turns_by_the_column_and_drives_by_distance_within_the_limits():
    ctl = _controller(limits={"reverse": True})
    # far (3 m) and 20 deg to the right: column right of the band -> clockwise turn, forward
    y = -3.0 * math.tan(math.radians(20))
    cmds = [ctl.on_target(_target(3.0, y), 0.1) for _ in range(40)]
    assert all(c.pan_rad == 0.0 for c in cmds)  # the seed's camera is fixed
    assert cmds[0].linear_mps == pytest.approx(0.05)  # limits.accel_mps2 0.5 over 0.1 s
    assert cmds[-1].linear_mps == pytest.approx(0.75)
    assert cmds[-1].angular_radps < 0.0
    assert {c.reason for c in cmds} == {"zhuang"}
    # straight ahead inside the dead band and the distance band: still
    ctl = _controller()
    assert ctl.goal(_target(2.0, 0.0))[:3] == (0.0, 0.0, 0.0)
    # too near: back off, but only where limits.reverse allows it
    assert _controller(limits={"reverse": True}).goal(_target(1.0, 0.0))[0] < 0.0
    assert _controller().on_target(_target(1.0, 0.0), 0.1).linear_mps == 0.0


def test_rule_zhuang_stops_with_the_pan_at_zero_when_lost_even_with_a_place_to_look():
    ctl = _controller()
    for _ in range(30):
        ctl.on_target(_target(3.0, 0.0), 0.1)
    lost = _target(0.0, 0.0, status="lost", look_x_m=1.0, look_y_m=2.0)
    cmds = [ctl.on_target(lost, 0.1) for _ in range(20)]
    assert cmds[-1].linear_mps == 0.0 and cmds[-1].angular_radps == 0.0
    assert all(c.pan_rad == 0.0 for c in cmds)


def test_an_unknown_rule_is_refused_naming_the_setting():
    from followbot.services.controller.core import ControllerSettings

    with pytest.raises(msgspec.ValidationError, match="rule"):
        msgspec.convert({"rule": "zhang"}, ControllerSettings)
