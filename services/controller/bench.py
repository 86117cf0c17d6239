"""Controller benchmark: what the obstacle guard adds per command (``make bench``).

Median over repeats of one ``FollowController.on_target`` with a 720-beam 270 deg scan,
target 2.5 m ahead at full speed, for: the thesis's rule alone (guard off), the guard with
nothing in reach (a room 6 m round), beside a wall (0.4 m to the right: the own arc is
checked and stands), a pillar ahead (every turn candidate is checked), and a corridor's
mouth with its corner 0.3 m ahead-right (every turn blocked; the escape off, the base
stands). Then the escape there: planning its end past the corner (once, as it begins:
every heading, up to three run lengths, and the way on from each end) and one step driving
to it. Also the scan's conversion to points (done once per scan in the node).

    python -m followbot.services.controller.bench
"""

from __future__ import annotations

import math

import numpy as np

from followbot.schemas import LaserScan, TrackState
from followbot.services.runtime.stats import median_us

from .avoid import scan_points, scan_view
from .core import ControllerSettings, FollowController
from .guard import ESCAPE_VIEW_MARGIN_RAD, GuardSettings

BEAMS = 720
FOV = math.radians(270.0)


def _ranges(case: str) -> np.ndarray:
    a = -FOV / 2 + FOV / (BEAMS - 1) * np.arange(BEAMS)
    r = np.full(BEAMS, 6.0)
    if case == "wall":  # y = -0.4 to the right
        right = np.sin(a) < -1e-3
        r[right] = np.minimum(r[right], 0.4 / -np.sin(a[right]))
    if case == "pillar":  # a 0.15 m pillar 0.9 m ahead
        b = a[np.abs(a) < 0.25]
        d = 0.9 * np.cos(b) - np.sqrt(np.maximum(0.15**2 - (0.9 * np.sin(b)) ** 2, 0.0))
        hit = (0.9 * np.abs(np.sin(b))) < 0.15
        r[np.abs(a) < 0.25] = np.where(hit, d, 6.0)
    if case == "corner":  # the wall x = 0.29 (y < -0.09), then y = -0.09 (x > 0.29)
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = np.where(s < -1e-6, -0.09 / s, np.inf)
            t_side = np.where(t_side * c >= 0.29, t_side, np.inf)
            t_front = np.where(c > 1e-6, 0.29 / c, np.inf)
            t_front = np.where(t_front * s <= -0.09, t_front, np.inf)
        r = np.minimum(r, np.minimum(t_side, t_front))
    return r


def _scan(case: str) -> LaserScan:
    return LaserScan.from_ranges(
        _ranges(case).astype(np.float32),
        stamp_ns=0,
        angle_min_rad=-FOV / 2,
        angle_increment_rad=FOV / (BEAMS - 1),
        range_min_m=0.05,
    )


def _median(fn) -> float:
    return median_us(fn, 300, warmup=False)


def main() -> None:
    target = TrackState(stamp_ns=0, status="tracking", x_m=2.5, y_m=0.0)
    rows = []
    rule = FollowController(ControllerSettings(guard=GuardSettings(enabled=False)))
    rows.append(("thesis rule alone", _median(lambda: rule.on_target(target, 0.12))))
    for case in ("room", "wall", "pillar", "corner"):
        scan = _scan(case)
        pts, view = scan_points(scan), scan_view(scan)
        # (the escape off: standing at the corner, every arc and heading is checked each step)
        ctl = FollowController(ControllerSettings(guard=GuardSettings(wait_s=0.0, escape_m=0.0)))
        reason = ctl.on_target(target, 0.12, pts, view).reason
        us = _median(lambda c=ctl, p=pts, w=view: c.on_target(target, 0.12, p, w))
        rows.append((f"guard, {case} ({reason})", us))
    # the escape (default): planning its end past the corner, once, when it begins; then
    # each step under way (turning towards the end, or driving there with its run checked)
    scan = _scan("corner")
    pts, view = scan_points(scan), scan_view(scan)
    ctl = FollowController(ControllerSettings(guard=GuardSettings(wait_s=0.0)))
    xy = (target.x_m, target.y_m)
    keep = (view.lo_rad + ESCAPE_VIEW_MARGIN_RAD, view.hi_rad - ESCAPE_VIEW_MARGIN_RAD)
    plan = ctl.guard.geometry.escape_goal  # what the controller calls as the escape begins
    rows.append(("escape, planning its end (corner)", _median(lambda: plan(pts, xy, True, keep))))
    goal = plan(pts, xy, True, keep)
    ahead = (math.hypot(*goal), 0.0)  # facing it: the run there is checked
    toward = ctl.guard.geometry.toward_goal
    rows.append(("escape, one step driving there", _median(lambda: toward(0.75, ahead, pts))))
    room = _scan("room")
    rows.append(("scan -> points", _median(lambda: scan_points(room))))
    print(f"controller, one command ({BEAMS}-beam scan), median of 300:")
    print("| case | µs |")
    print("|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.0f} |")


if __name__ == "__main__":
    main()
