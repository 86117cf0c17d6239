"""Controller: the thesis rule, limits that always hold (hypothesis), stops."""

from __future__ import annotations

import itertools
import math

import msgspec
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from followbot.schemas import TrackState
from followbot.services.controller.core import (
    ControllerSettings,
    FollowController,
    LimitsSettings,
    PanSettings,
)
from followbot.services.controller.guard import GuardSettings
from followbot.services.controller.node import ControllerNodeSettings
from followbot.services.runtime.settings import SettingsError, load_settings

DEG = math.pi / 180
OFF = GuardSettings(enabled=False)
RULE = ControllerSettings(guard=OFF)  # the thesis rule alone (test_avoid.py: guard)


def target(x, y, vx=0.0, vy=0.0, status="tracking"):
    return TrackState(stamp_ns=0, status=status, x_m=x, y_m=y, vx_mps=vx, vy_mps=vy)


@pytest.mark.parametrize(
    ("r", "speed", "expected", "reason"),
    [
        (1.0, 0.5, 0.0, "stop_close"),
        (1.3, 0.4, 0.4, "match_speed"),
        (1.3, 2.0, 2.0, "match_speed"),  # the goal; the limits cap it (below)
        (2.5, 0.1, 0.75, "max_speed"),
    ],
)
def test_translation_rule_of_thesis_4_6(r, speed, expected, reason):
    v, w, pan, why = FollowController(RULE).goal(target(r, 0.0, vx=speed))
    assert (v, w, pan, why) == (pytest.approx(expected), 0.0, 0.0, reason)


def test_turns_only_outside_the_6_degree_dead_band_and_pan_is_the_heading():
    ctl = FollowController(RULE)
    for deg, turns in [(5.0, False), (-5.9, False), (6.5, True), (-30.0, True)]:
        th = deg * DEG
        _, w, pan, _ = ctl.goal(target(2.0 * math.cos(th), 2.0 * math.sin(th)))
        assert (w != 0.0) == turns
        if turns:
            assert math.copysign(1, w) == math.copysign(1, th)
        assert pan == pytest.approx(th)


def test_the_rule_follows_the_filter_estimate_not_the_lone_leg_report():
    """The tracker reports (1.6, 0.4) = its filter estimate (1.45, 0.3) plus a lone-leg shift
    (0.15, 0.1): the rule follows the filter estimate (r 1.48 m: match speed; the heading
    11.7 deg), not the report (r 1.65 m would be full speed)."""
    t = msgspec.structs.replace(target(1.6, 0.4, vx=0.3), shift_x_m=0.15, shift_y_m=0.1)
    v, _, pan, reason = FollowController(RULE).goal(t)
    assert pan == pytest.approx(math.atan2(0.3, 1.45))
    assert (v, reason) == (0.3, "match_speed")


def test_coasting_keeps_the_previous_goal_lost_stops():
    ctl = FollowController(RULE)
    for _ in range(40):
        c = ctl.on_target(target(2.5, 0.5), 0.12)
    v_tracking = c.linear_mps
    assert v_tracking == pytest.approx(0.75)
    c = ctl.on_target(target(0.0, 0.0, status="coasting"), 0.12)
    assert c.linear_mps == pytest.approx(v_tracking) and c.reason == "coasting"
    for _ in range(10):
        c = ctl.on_target(target(0.0, 0.0, status="lost"), 0.12)
    assert (c.linear_mps, c.angular_radps, c.reason) == (0.0, 0.0, "lost")


def test_lost_the_base_stays_still_and_the_camera_turns_to_look_within_its_limits():
    """pan.look_when_lost: a lost target with someone to look at (TrackState.look_*) turns the
    camera there at 90 deg/s, at most 100 deg; the base never moves. Off: the camera holds."""
    for on in (True, False):
        ctl = FollowController(ControllerSettings(guard=OFF, pan=PanSettings(look_when_lost=on)))
        lost = TrackState(
            stamp_ns=0, frame_id="base_link", status="lost",
            look_track_id=4, look_x_m=-1.0, look_y_m=1.0,  # 135 deg left: beyond the limit
        )  # fmt: skip
        pans = []
        for _ in range(20):
            c = ctl.on_target(lost, 0.12)
            assert (c.linear_mps, c.angular_radps, c.reason) == (0.0, 0.0, "lost")
            pans.append(math.degrees(c.pan_rad))
        if on:
            assert pans[0] == pytest.approx(90 * 0.12)
            assert pans[-1] == pytest.approx(100.0)
            assert all(b - a <= 90 * 0.12 + 1e-9 for a, b in itertools.pairwise(pans))
        else:
            assert pans == [0.0] * 20
    nowhere = TrackState(stamp_ns=0, frame_id="base_link", status="lost")
    assert FollowController(RULE).on_target(nowhere, 0.12).pan_rad == 0.0  # -1 at (0, 0)
    # nobody tracked there yet, but a point to look at (where the lost target should be)
    point = TrackState(stamp_ns=0, frame_id="base_link", status="lost", look_x_m=0.0, look_y_m=2.0)
    c = FollowController(RULE).on_target(point, 0.12)
    assert (c.linear_mps, c.angular_radps) == (0.0, 0.0)
    assert math.degrees(c.pan_rad) == pytest.approx(90 * 0.12)


def test_coasting_keeps_the_base_s_command_and_the_camera_s_aim():
    """Coasting is the previous goal, base and camera (thesis 3.6.2.8); the camera turns to a
    look only while the target is lost (the tracker names none while it coasts)."""
    ctl = FollowController(RULE)
    for _ in range(40):
        c = ctl.on_target(target(2.5, 0.0), 0.12)
    v_tracking = c.linear_mps
    hidden = TrackState(stamp_ns=0, frame_id="base_link", status="coasting", x_m=2.5)
    for _ in range(8):
        c = ctl.on_target(hidden, 0.12)
        assert c.linear_mps == pytest.approx(v_tracking) and c.reason == "coasting"
        assert c.pan_rad == pytest.approx(0.0, abs=1e-9)


def test_the_watchdog_brakes_to_rest_within_the_deceleration_limit():
    ctl = FollowController(RULE)
    for _ in range(40):
        ctl.on_target(target(3.0, 1.0), 0.12)
    assert ctl.v > 0.7
    n = 0
    while not ctl.at_rest:
        c = ctl.stop(0.05)
        n += 1
        assert n < 100
    assert c.reason == "watchdog" and c.linear_mps == 0.0
    assert n <= math.ceil(0.75 / (2.0 * 0.05)) + 1  # 2 m/s^2 braking


finite = st.floats(-20, 20, allow_nan=False)
events = st.lists(
    st.tuples(
        st.sampled_from(["tracking", "coasting", "lost", "initialising", "watchdog"]),
        finite,
        finite,
        finite,
        finite,
        st.floats(0.0, 0.5),
    ),
    min_size=1,
    max_size=60,
)


@settings(max_examples=300, deadline=None)
@given(events)
def test_limits_always_hold(seq):
    s = ControllerSettings()  # the obstacle guard on, a pillar 0.8 m ahead to turn it
    ctl = FollowController(s)
    ang = np.linspace(0.0, 2 * math.pi, 24)
    pillar = np.column_stack([0.8 + 0.15 * np.cos(ang), 0.15 * np.sin(ang)])
    v0 = w0 = p0 = 0.0
    tol = 1e-9
    for kind, x, y, vx, vy, dt in seq:
        if kind == "watchdog":
            c = ctl.stop(dt)
        else:
            c = ctl.on_target(target(x, y, vx, vy, status=kind), dt, pillar)
        lim = s.limits
        assert 0.0 <= c.linear_mps <= lim.max_speed_mps + tol  # no reverse by default
        assert abs(c.angular_radps) <= lim.max_turn_deg_s * DEG + tol
        assert abs(c.pan_rad) <= s.pan.limit_deg * DEG + tol
        dv = c.linear_mps - v0
        limit = (lim.accel_mps2 if abs(c.linear_mps) > abs(v0) else lim.decel_mps2) * dt
        assert abs(dv) <= limit + tol
        assert abs(c.angular_radps - w0) <= lim.turn_accel_deg_s2 * DEG * dt + tol
        assert abs(c.pan_rad - p0) <= s.pan.rate_deg_s * DEG * dt + tol
        v0, w0, p0 = c.linear_mps, c.angular_radps, c.pan_rad


def test_non_finite_goal_is_refused():
    ctl = FollowController(RULE)
    c = ctl._limit(float("nan"), 0.0, 0.0, "x", 0.1)
    assert (c.linear_mps, c.reason) == (0.0, "invalid")


def test_the_hardware_caps_bound_the_settings_and_every_command():
    with pytest.raises(
        ValueError,
        match=r"limits\.max_speed_mps 50\.0 exceeds limits\.hardware_max_speed_mps 1\.0",
    ):
        LimitsSettings(max_speed_mps=50.0)
    with pytest.raises(ValueError, match=r"max_turn_deg_s 400\.0 exceeds"):
        LimitsSettings(max_turn_deg_s=400.0)
    with pytest.raises(SettingsError, match=r"limits\.max_speed_mps 50\.0 exceeds"):
        load_settings(ControllerNodeSettings, overrides=["limits.max_speed_mps=50"])
    with pytest.raises(msgspec.ValidationError):  # no base is rated beyond the wire's bound
        msgspec.convert({"limits": {"hardware_max_speed_mps": 10.0}}, ControllerSettings)
    ctl = FollowController(
        ControllerSettings(limits=LimitsSettings(max_speed_mps=1.0, accel_mps2=100.0), guard=OFF)
    )
    far = TrackState(stamp_ns=1, status="tracking", x_m=9.0, y_m=0.0)
    c = ctl.on_target(far, 1.0)
    assert c.linear_mps == 1.0 and c.reason == "max_speed"


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("max_speed_mps=0.5", "limits.max_speed_mps"),
        ("pan_to_look=false", "pan.look_when_lost"),
        ("avoid_obstacles=false", "guard.enabled"),
        ("avoid_escape_m=0", "guard.escape_m"),
    ],
)
def test_a_moved_setting_is_refused_with_its_new_key(old, new, tmp_path):
    """The settings nested by role: an old flat key, in a file or --set, names the new one."""
    with pytest.raises(SettingsError, match=rf"--set: {old.split('=')[0]} was renamed: set {new}"):
        load_settings(ControllerNodeSettings, overrides=[old])
    key, value = old.split("=")
    path = tmp_path / "controller.yaml"
    path.write_text(f"{key}: {value}\n")
    with pytest.raises(SettingsError, match=rf"{new} instead"):
        load_settings(ControllerNodeSettings, config_file=path)
    *sections, last = new.split(".")
    nested = load_settings(ControllerNodeSettings, overrides=[f"{new}={value}"])
    assert getattr(getattr(nested, sections[0]), last) == yaml.safe_load(value)


@pytest.mark.parametrize("key", ["follow_report", "avoid_memory_s"])
def test_a_removed_experiment_is_refused_with_the_reason(key):
    with pytest.raises(SettingsError, match=rf"{key} was removed \(.*docs/tracker_log\.md"):
        load_settings(ControllerNodeSettings, overrides=[f"{key}=0"])


def test_at_most_25_top_level_settings_the_rest_nested_by_role():
    assert len(ControllerNodeSettings.__struct_fields__) <= 25
    s = load_settings(ControllerNodeSettings, overrides=["guard.wait_s=0"])
    assert s.guard.wait_s == 0.0 and s.guard.escape_m == 0.3  # the section's other defaults
