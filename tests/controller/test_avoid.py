"""Controller's obstacle guard (avoid.py): unchanged in the open, turned or stopped short of
what the laser sees, and in closed loop with the simulator the base no longer runs into walls."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from followbot.schemas import LaserScan, TrackState
from followbot.services.controller.avoid import (
    ObstacleGuard,
    moved_into_frame,
    scan_points,
    scan_view,
)
from followbot.services.controller.core import ControllerSettings, FollowController
from followbot.services.controller.guard import GuardSettings
from followbot.services.runtime.mount import LaserMount
from followbot.services.sim.scenario import load_builtin
from followbot.services.sim.simulation import Simulation

DEG = math.pi / 180


def guard(**kw) -> ObstacleGuard:
    args = dict(
        body_radius_m=0.25,
        margin_m=0.05,
        horizon_s=1.0,
        decel_mps2=2.0,
        max_turn_radps=100 * DEG,
        turn_candidates=21,
        min_speed_mps=0.05,
        ignore_near_target_m=0.5,
    )
    return ObstacleGuard(**{**args, **kw})


def line(x0, y0, x1, y1, n=200) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.array([x0, y0]) + t * np.array([x1 - x0, y1 - y0])


def test_scan_points_drop_no_returns_and_apply_the_mount():
    r = np.array([1.0, np.nan, np.inf, 0.0, 0.01, 50.0, 2.0])
    scan = LaserScan.from_ranges(
        r, stamp_ns=0, angle_min_rad=-math.pi / 2, angle_increment_rad=math.pi / 6,
        range_min_m=0.05, range_max_m=30.0,
    )  # fmt: skip
    pts = scan_points(scan, LaserMount(x_m=0.1))
    assert pts.shape == (2, 2)
    assert pts[0] == pytest.approx([0.1, -1.0])
    assert pts[1] == pytest.approx([0.1 + 2.0 * math.cos(math.pi / 2), 2.0])
    # off-centre and turned 90 deg left: the beam to the laser's right points ahead of the base
    turned = scan_points(scan, LaserMount(x_m=0.5, y_m=-0.2, yaw_deg=90.0))
    assert turned[0] == pytest.approx([0.5 + 1.0, -0.2])
    assert turned[1] == pytest.approx([0.5 - 2.0, -0.2], abs=1e-9)


def test_in_the_open_and_beside_a_wall_it_runs_alongside_the_command_stands():
    g = guard()
    assert g.apply(0.75, 0.3, np.empty((0, 2)), None) == (0.75, 0.3, None)
    far = line(-1.0, -1.0, 4.0, -1.0)  # a wall 1 m to the right
    assert g.apply(0.75, 0.0, far, None) == (0.75, 0.0, None)
    # already within the margin (0.28 m) and sliding along: free; closing in: turned away
    near = line(-1.0, -0.28, 4.0, -0.28)
    assert g.apply(0.75, 0.0, near, None) == (0.75, 0.0, None)
    v, w, why = g.apply(0.75, -0.3, near, None)
    assert (v, why) == (0.75, "avoid_turn") and w >= 0.0


def test_a_pillar_ahead_is_passed_by_the_nearest_free_turn():
    ang = np.linspace(0.0, 2 * math.pi, 60)
    pillar = np.column_stack([1.0 + 0.15 * np.cos(ang), 0.15 * np.sin(ang)])
    v, w, why = guard().apply(0.75, 0.1, pillar, (3.0, 0.0))
    assert why == "avoid_turn" and v == 0.75 and abs(w) > 0.1
    # and the chosen arc is free: sample it
    k = w / v
    s = np.linspace(0.0, guard().reach_m(v), 50)
    xy = np.column_stack([np.sin(k * s) / k, (1 - np.cos(k * s)) / k])
    d = np.hypot(xy[:, None, 0] - pillar[None, :, 0], xy[:, None, 1] - pillar[None, :, 1])
    assert d.min() >= 0.30 - 1e-9


def test_a_dead_end_slows_then_stops_and_the_target_s_own_legs_are_no_obstacle():
    g = guard()
    box = np.vstack([line(0.7, -3, 0.7, 3), line(-1, 0.35, 0.7, 0.35), line(-1, -0.35, 0.7, -0.35)])
    v, _w, why = g.apply(0.75, 0.0, box, None)
    assert why in ("avoid_slow", "avoid_stop") and v < 0.75
    # something 1 cm beyond the margin, dead ahead and all round: stop, turn as told
    ring = 0.31 * np.column_stack([np.cos(np.linspace(-2, 2, 40)), np.sin(np.linspace(-2, 2, 40))])
    assert g.apply(0.75, 0.2, ring, None) == (0.0, 0.2, "avoid_stop")
    legs = np.array([[1.0, 0.1], [1.0, -0.1]])  # the target, 1 m ahead (within the reach)
    assert g.apply(0.75, 0.0, legs, (1.0, 0.0)) == (0.75, 0.0, None)
    assert g.apply(0.75, 0.0, legs, None)[2] is not None  # someone else there: obstacle


def test_the_controller_stops_without_a_scan_and_leaves_the_thesis_rule_alone_when_off():
    t = TrackState(stamp_ns=0, status="tracking", x_m=3.0, y_m=0.0)
    on = FollowController(ControllerSettings())
    c = on.on_target(t, 0.12, None)
    assert (c.linear_mps, c.reason) == (0.0, "no_scan")
    c = on.on_target(t, 0.12, np.empty((0, 2)))
    assert c.linear_mps > 0.0 and c.reason == "max_speed"
    off = FollowController(ControllerSettings(guard=GuardSettings(enabled=False)))
    assert off.guard is None and off.on_target(t, 0.12, None).reason == "max_speed"


def _follow(
    avoid: bool,
    seconds: float = 14.0,
    seed: int | None = None,
    **settings,
) -> tuple[int, float]:
    """ristic_wall_corridor's target along the wall, the controller on the truth (no
    tracker): (bumps, distance to the target at the end); ``settings``: guard settings."""
    scenario = load_builtin("ristic_wall_corridor")
    if seed is not None:
        scenario = msgspec.structs.replace(scenario, seed=seed)
    sim = Simulation(scenario)
    ctl = FollowController(ControllerSettings(guard=GuardSettings(enabled=avoid, **settings)))
    period = round(1e9 / sim.scenario.laser.rate_hz)
    t = 0
    while t < seconds * 1e9:
        t += period
        sim.advance_to(t)
        scan, truth = sim.scan(), sim.truth()
        p = next(q for q in truth.people if q.is_target)
        st = TrackState(
            stamp_ns=t,
            status="tracking",
            x_m=p.robot_x_m,
            y_m=p.robot_y_m,
            vx_mps=p.robot_vx_mps,
            vy_mps=p.robot_vy_mps,
        )
        c = ctl.on_target(st, period / 1e9, scan_points(scan), scan_view(scan))
        sim.command_velocity(c.linear_mps, c.angular_radps)
    return sim.robot.bumps, math.hypot(p.robot_x_m, p.robot_y_m)


def test_closed_loop_along_a_wall_the_guard_keeps_the_base_off_it_and_with_its_target():
    bumps, dist = _follow(avoid=False)
    assert bumps >= 1 and dist > 3.0  # the thesis rule alone: stuck on the wall, left behind
    bumps, dist = _follow(avoid=True)
    assert bumps == 0 and dist < 2.0


def corridor_mouth() -> np.ndarray:
    """A corridor's mouth seen from a base 0.09 m inside its right wall's line, the corner
    0.3 m ahead-right (ristic_wall_corridor, seed 1, where the base stood 5 s): the wall
    before the mouth to the right, the corridor's right wall ahead from the corner on."""
    return np.vstack([line(0.29, -3.0, 0.29, -0.09), line(0.29, -0.09, 5.0, -0.09)])


def test_the_controller_lets_the_escape_start_only_after_standing_a_while():
    ctl = FollowController(
        ControllerSettings(guard=GuardSettings(escape_m=0.3, escape_after_s=1.0, wait_s=0.0))
    )
    t = TrackState(stamp_ns=0, status="tracking", x_m=3.0, y_m=0.1)
    reasons = [ctl.on_target(t, 0.12, corridor_mouth()).reason for _ in range(12)]
    first = reasons.index("avoid_escape")
    assert set(reasons[:first]) == {"avoid_stop"} and first == 9  # 1.0 s / 0.12 s, rounded up
    assert set(reasons[first:]) == {"avoid_escape"}  # and it keeps escaping
    lost = TrackState(stamp_ns=0, status="lost")
    assert ctl.on_target(lost, 0.12, corridor_mouth()).reason == "lost"


def test_stopped_at_a_corridor_s_mouth_the_base_turns_to_the_free_heading_then_drives():
    walls = corridor_mouth()
    target = (3.0, 0.1)
    # without the escape: every forward arc closes in on the corner, so the base stands
    assert guard().apply(0.6, 0.0, walls, target) == (0.0, 0.0, "avoid_stop")
    g = guard(escape_m=0.3)
    v, w, why = g.apply(0.6, 0.0, walls, target)
    assert (why, v) == ("avoid_escape", 0.0) and w > 0.0  # turns left, on the spot
    # facing the heading it turned to: drives along it, slow enough to stop within 0.3 m,
    # the run keeping the body clear of the corner
    free = g.headings[g.free_headings(walls)]
    phi = float(free[np.argmin(np.abs(free - math.atan2(target[1], target[0])))])
    c, s_ = math.cos(phi), math.sin(phi)
    turned = walls @ np.array([[c, -s_], [s_, c]])  # the points in the turned base's frame
    v, w, why = g.apply(0.6, 0.0, turned, (target[0] * c + target[1] * s_, 0.0))
    assert why == "avoid_escape" and 0.0 < v <= g.speed_for(0.3) and w == 0.0
    run = np.column_stack([np.linspace(0.0, 0.3, 31), np.zeros(31)])
    d = np.hypot(run[:, None, 0] - turned[None, :, 0], run[:, None, 1] - turned[None, :, 1])
    assert d.min() >= 0.25
    # no target known (lost): no escape, it stands; nothing free towards the target either
    assert g.apply(0.6, 0.0, walls, None)[2] == "avoid_stop"
    ring = 0.27 * np.column_stack([np.cos(np.linspace(-2, 2, 40)), np.sin(np.linspace(-2, 2, 40))])
    assert g.apply(0.6, 0.0, ring, (3.0, 0.0)) == (0.0, 0.0, "avoid_stop")


def _way_on_clearance(end, target, walls, run_m=1.0) -> float:
    """Least distance from ``walls`` to the straight way from ``end`` towards ``target``
    (``run_m`` long): what the rule's own arc needs free after the escape."""
    end, target = np.asarray(end), np.asarray(target)
    u = (target - end) / np.linalg.norm(target - end)
    way = end + np.linspace(0.0, run_m, 101)[:, None] * u
    return float(np.hypot(*(way[:, None, :] - walls[None, :, :]).transpose(2, 0, 1)).min())


def test_the_escape_ends_past_the_corner_not_merely_beside_it():
    """The nearest free heading (45 deg left) ends 0.3 m on, still behind the corner: the way
    on to the target from there closes in on it again, so the rule stops the base once more
    (ristic_wall_corridor seed 1, twentieth session). ``onward``: the end from which the
    way on is free for the body and the margin (0.30 m)."""
    walls, target = corridor_mouth(), (3.0, 0.1)
    g = guard(escape_m=0.3)
    near = g.escape_goal(walls, target)
    past = g.escape_goal(walls, target, onward=True)
    assert math.atan2(near[1], near[0]) == pytest.approx(math.radians(45.0))
    assert math.hypot(*near) == pytest.approx(0.3) and math.hypot(*past) >= 0.3 - 1e-9
    assert _way_on_clearance(near, target, walls) < 0.30 <= _way_on_clearance(past, target, walls)
    # the run there keeps the body clear too
    run = np.linspace(0.0, 1.0, 31)[:, None] * np.asarray(past)
    assert np.hypot(*(run[:, None, :] - walls[None, :, :]).transpose(2, 0, 1)).min() >= 0.26
    # nothing past the corner within reach (a wall all round but behind): as without
    ring = 0.6 * np.column_stack(
        [np.cos(np.linspace(-1.5, 1.5, 60)), np.sin(np.linspace(-1.5, 1.5, 60))]
    )
    assert g.escape_goal(ring, (3.0, 0.0), onward=True) == g.escape_goal(ring, (3.0, 0.0))


def test_toward_the_escape_s_end_the_base_turns_first_then_drives_there():
    g = guard(escape_m=0.3)
    v, w, why = g.toward_goal(0.75, (0.0, 0.3), np.empty((0, 2)))
    assert (why, v) == ("avoid_escape", 0.0) and w > 0.0  # 90 deg left: on the spot
    v, w, why = g.toward_goal(0.75, (0.3, 0.0), np.empty((0, 2)))
    assert why == "avoid_escape" and v == pytest.approx(g.speed_for(0.3)) and w == 0.0
    v, w, _ = g.toward_goal(0.75, (0.3, 0.01), np.empty((0, 2)))
    assert v > 0.0 and w > 0.0  # a little off: steering onto it as it drives
    assert g.toward_goal(0.75, (0.02, 0.0), np.empty((0, 2))) is None  # there
    wall = line(0.35, -1.0, 0.35, 1.0)  # something now across the way there: given up
    assert g.toward_goal(0.75, (0.3, 0.0), wall) is None


def test_a_begun_escape_is_driven_on_though_the_way_clears_and_dropped_when_lost():
    settings = dict(escape_m=0.3, escape_after_s=0.0, wait_s=0.0)
    t = TrackState(stamp_ns=0, status="tracking", x_m=3.0, y_m=0.1)
    for commit, then in ((True, "avoid_escape"), (False, "max_speed")):
        guard_settings = GuardSettings(escape_commit=commit, **settings)
        ctl = FollowController(ControllerSettings(guard=guard_settings))
        assert ctl.on_target(t, 0.12, corridor_mouth()).reason == "avoid_escape"
        assert (ctl.guard.escape_goal is not None) == commit
        # the next scan shows nothing in the way: committed, the base still escapes first
        assert ctl.on_target(t, 0.12, np.empty((0, 2))).reason == then
    lost = TrackState(stamp_ns=0, status="lost")  # lost: it stops, and the escape is over
    ctl = FollowController(ControllerSettings(guard=GuardSettings(**settings)))
    ctl.on_target(t, 0.12, corridor_mouth())
    assert ctl.on_target(lost, 0.12, corridor_mouth()).reason == "lost"
    assert ctl.guard.escape_goal is None
    assert ctl.on_target(t, 0.12, np.empty((0, 2))).reason == "max_speed"


def test_closed_loop_at_the_corridor_s_mouth_the_escape_takes_the_base_in():
    """ristic_wall_corridor seed 1, 30 s, the controller on the truth: without the escape
    the base stands at the mouth and the target walks away (5.5 m ahead); escaping afresh
    each step it gets in late (2.8 m); with the escape driven to its end past the corner
    (guard.escape_commit, default) it follows close (1.6 m)."""
    bumps, dist = _follow(True, 30.0, seed=1, escape_m=0.0)
    assert bumps == 0 and dist > 5.0
    bumps, dist = _follow(True, 30.0, seed=1, escape_m=0.3, escape_commit=False)
    assert bumps == 0 and 2.5 < dist < 3.5
    bumps, dist = _follow(True, 30.0, seed=1, escape_m=0.3)
    assert bumps == 0 and dist < 2.0


def test_someone_on_the_line_to_the_target_is_waited_for_then_gone_round():
    """guard.wait_s: a passer-by 0.8 m ahead on the line to the target 2.5 m away: the base
    slows to stop short and waits 1.5 s; if they do not clear the line, it goes round."""
    ang = np.linspace(0.0, 2 * math.pi, 40)
    passer = np.column_stack([0.8 + 0.12 * np.cos(ang), 0.12 * np.sin(ang)])
    g = guard(between_m=0.125)
    v, w, why = g.apply(0.75, 0.0, passer, (2.5, 0.0), may_swerve=False)
    assert why == "avoid_wait" and v < 0.75 and w == 0.0
    assert g.apply(0.75, 0.0, passer, (2.5, 0.0), may_swerve=True)[2] == "avoid_turn"
    # beside the line (a wall to the right, 0.28 m off it), no waiting: turned away at once
    wall = line(-1.0, -0.28, 4.0, -0.28)
    assert g.apply(0.75, -0.3, wall, (2.5, 0.0), may_swerve=False)[2] == "avoid_turn"
    # the same returns every scan: with wait_moving_only that is a still thing, gone round
    # at once; without, waited for (the timing tested here)
    still = FollowController(ControllerSettings())
    t0 = TrackState(stamp_ns=0, status="tracking", x_m=2.5, y_m=0.0)
    assert [still.on_target(t0, 0.12, passer).reason for _ in range(2)] == [
        "avoid_wait",  # no scan before: waited for
        "avoid_turn",
    ]
    ctl = FollowController(
        ControllerSettings(guard=GuardSettings(wait_s=1.5, wait_moving_only=False))
    )
    t = TrackState(stamp_ns=0, status="tracking", x_m=2.5, y_m=0.0)
    reasons = [ctl.on_target(t, 0.12, passer).reason for _ in range(20)]
    waited = reasons.index("avoid_turn")
    assert set(reasons[:waited]) <= {"avoid_wait"} and 12 <= waited <= 14  # 1.5 s / 0.12 s
    # the line clears: the rule's own command again, and the next passer-by is waited for
    assert ctl.on_target(t, 0.12, np.empty((0, 2))).reason == "max_speed"
    assert ctl.on_target(t, 0.12, passer).reason == "avoid_wait"


def test_moved_into_frame_follows_the_base_s_own_motion():
    p = np.array([[1.0, 0.0]])
    assert moved_into_frame(p, 0.5, 0.0, 1.0) == pytest.approx(np.array([[0.5, 0.0]]))
    assert moved_into_frame(p, 0.0, math.pi / 2, 1.0) == pytest.approx(np.array([[0.0, -1.0]]))
    # an arc: a point that stays put in the world ends where the robot's new frame puts it
    v, w, dt = 0.5, 0.8, 0.5
    th = w * dt
    x, y = v / w * math.sin(th), v / w * (1 - math.cos(th))
    q = moved_into_frame(np.array([[2.0, 1.0]]), v, w, dt)[0]
    back = np.array([x + math.cos(th) * q[0] - math.sin(th) * q[1],
                     y + math.sin(th) * q[0] + math.cos(th) * q[1]])  # fmt: skip
    assert back == pytest.approx([2.0, 1.0])


def test_with_wait_moving_only_a_pillar_on_the_line_is_gone_round_at_once():
    ang = np.linspace(0.0, 2 * math.pi, 40)
    thing = np.column_stack([0.8 + 0.12 * np.cos(ang), 0.12 * np.sin(ang)])
    g = guard(wait_moving_only=True)
    # where it was a scan ago: a pillar; 0.1 m to the side: a passer-by
    assert g.apply(0.75, 0.0, thing, (2.5, 0.0), may_swerve=False, previous=thing)[2] == (
        "avoid_turn"
    )
    walked = thing + np.array([0.0, 0.1])
    assert g.apply(0.75, 0.0, thing, (2.5, 0.0), may_swerve=False, previous=walked)[2] == (
        "avoid_wait"
    )
    # no scan before: waited for, as without the setting
    assert g.apply(0.75, 0.0, thing, (2.5, 0.0), may_swerve=False)[2] == "avoid_wait"


def test_the_scan_s_view_is_its_beams_seen_from_the_laser():
    """scan_view: a +-50 deg scan (201 beams of 0.5 deg) mounted 0.1 m ahead of the base."""
    scan = LaserScan(
        stamp_ns=1, angle_min_rad=-math.radians(50.0), angle_increment_rad=math.radians(0.5),
        range_min_m=0.05, range_max_m=8.0, ranges=np.full(201, 3.0, dtype=np.float32),
    )  # fmt: skip
    view = scan_view(scan, LaserMount(x_m=0.1))
    assert (view.x_m, view.y_m) == (0.1, 0.0)
    assert [math.degrees(b) for b in view[2:]] == [pytest.approx(-50.0), pytest.approx(50.0)]
    # the same laser at (0.5, -0.2), turned 90 deg left: it covers the base's left, not ahead
    turned = scan_view(scan, LaserMount(x_m=0.5, y_m=-0.2, yaw_deg=90.0))
    assert (turned.x_m, turned.y_m) == (0.5, -0.2)
    assert [math.degrees(b) for b in turned[2:]] == [pytest.approx(40.0), pytest.approx(140.0)]


def test_the_limited_arc_s_check_is_for_contact_not_the_margin():
    """A return 0.5 m ahead, 0.28 m beside the straight path: the goal's check turns or slows
    the command (inside the body and margin, 0.30 m), the check of the limited command
    (guard.check_limited: the body and 0.01 m, 0.26 m) lets it pass; 0.2 m beside it blocks
    both."""
    g = guard()
    for lateral, contact in ((0.28, False), (0.2, True)):
        pts = np.array([[0.5, lateral]])
        assert g.apply(0.5, 0.0, pts, None)[2] is not None
        assert g.blocked(0.5, 0.0, pts, None) == contact


@pytest.mark.parametrize("check", [True, False])
def test_the_arc_the_limits_leave_is_checked_too(check):
    """guard.check_limited: at rest, a post 0.27 m abeam to the left, the target 45 deg left.
    The rule's arc (0.75 m/s, 1.18 rad/s) passes clear of the post, but the limits leave
    0.06 m/s at 0.63 rad/s this step -- a 0.1 m radius that swings the body within 0.26 m of
    the post in its second. Checked, the base turns on the spot instead (avoid_stop)."""
    ctl = FollowController(ControllerSettings(guard=GuardSettings(check_limited=check)))
    post = np.array([[0.0, 0.27]])
    target = TrackState(stamp_ns=0, status="tracking", x_m=2.0, y_m=2.0)
    g = ctl.guard.geometry
    assert g.apply(0.75, 1.5 * math.pi / 4, post, (2.0, 2.0))[2] is None  # goal free
    assert g.blocked(0.06, 0.63, post, (2.0, 2.0))  # the limited arc is not
    c = ctl.on_target(target, 0.12, post)
    assert c.angular_radps == pytest.approx(0.63, abs=0.01)
    assert (c.linear_mps, c.reason) == ((0.0, "avoid_stop") if check else (0.06, "max_speed"))
