"""Obstacle guard: the thesis's command, turned or slowed only where it would run into something.

Beyond the thesis (its robot followed in open space). The rule heads straight for the target,
so a robot following someone round a pillar, along a wall or through a door cuts the corner:
the simulator's bumper (services/sim/robot.py) stops it there and the target walks away.
The guard looks along the arc the base would drive, with the last laser scan (every return
an obstacle except those within ``ignore_near_target_m`` of the target's estimate):

* The arc of the command (v, w) is followed for ``L = v H + v^2 / (2 b)`` -- what the base
  travels in the horizon H plus its braking distance at b -- sampled every ``step_m``. Its
  free length is how far the base gets along it before its disc (``body_radius_m`` +
  ``margin_m``) comes nearer an obstacle than that (or, when it starts nearer, nearer than it
  starts: sliding along a wall it already touches is free, closing in is not).
* Free for L: the command stands, unchanged (so in open space the thesis's rule is all there
  is).
* Else the same speed on ``turn_candidates`` arcs from -w_max to w_max: of those free for L
  that still lead towards the target (their end at least ``min_progress`` of the command's
  own arc's gain nearer it; when that arc gains nothing, no worse), the one whose turn rate
  is nearest the command's (reason ``avoid_turn``). A way round that leads away is no way:
  a robot 1.2 m from someone walking round a pillar would drive off past the pillar's other
  side and lose them.
* None: the command's own arc at the speed that stops within its free length (the same
  curvature, so the same arc; reason ``avoid_slow``); under ``min_speed_mps`` the base stops
  and only turns as the rule says, on the spot (reason ``avoid_stop``; a disc turning on
  the spot touches nothing).
* Stopped so with the target known (``escape_m`` > 0, reason ``avoid_escape``): the base would
  stand there for good when the only way on is sideways first -- at a corridor's mouth with
  the corner 0.3 m ahead-right and the target straight on, every forward arc closes in on the
  corner. So the guard looks for the heading nearest the target's bearing (within 90 deg of
  it, inside +-90 deg of ahead) along which a straight run of ``escape_m`` keeps the disc
  clear of everything by ``escape_clear_m`` (the margin may be used here, the body never).
  Straight ahead is such a heading and no more than ``escape_slack`` further from the
  target's bearing: the base drives on at the speed that stops within ``escape_m``.
  Otherwise it turns on the spot towards that heading. The next command starts from the new
  pose as before: the rule's own arc first, then the turns, and the escape only when those
  are stopped again. That is :meth:`ObstacleGuard.apply` alone. The controller's default
  (guard.py, ``guard.escape_commit``) plans the escape instead:
  :meth:`ObstacleGuard.escape_goal` with ``onward`` picks the end point past the corner --
  the shortest run (1, 1.5, 2 x ``escape_m``), then the heading nearest the target's, from
  whose end the straight way on to the target is free for the disc (ONWARD_M, short of the
  target's legs), the target kept inside the laser's view -- and
  :meth:`ObstacleGuard.toward_goal` drives there, turning on the spot first, before the rule
  has the base again. Recomputed each step, the rule's own arc, free again after a few
  centimetres, would turn the base back into the corner.

* Someone crossing between the robot and its target is waited for, not gone round: while
  what blocks the arc includes something on the line to the target (within ``between_m`` of
  it) that moved since the scan before (``wait_moving_only``: a box or a pillar there is
  gone round at once), the base first slows on its own arc to stop short and waits, up to
  the controller's ``guard.wait_s`` (reason ``avoid_wait``); only then does it go round. A
  passer-by clears the line within a second or two; a pillar does not. Swerving at full
  speed round a passer-by turns the laser's view away from the target just as it is hidden.

Turning on the spot and standing still are always free. The scan is in the laser frame, at the
robot's ``laser_mount`` (x, y, yaw) in the base frame; its returns are turned into the base
frame first. Returns outside its field of view are not known (the guard protects the way the
laser looks only). The state the guard keeps from one command to the next (waiting, standing,
the escape under way) is guard.py's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from followbot.schemas import LaserScan
from followbot.services.common.geometry import transform_points
from followbot.services.common.scan import beam_geometry, valid_mask
from followbot.services.runtime.mount import LaserMount

__all__ = [
    "MOVED_M",
    "MOVED_SHARE",
    "ObstacleGuard",
    "ScanView",
    "moved_into_frame",
    "scan_points",
    "scan_view",
]

MOVED_M = 0.03
"""wait_moving_only: a return this far from every return of the scan before has moved."""
MOVED_SHARE = 0.1
"""... and something on the line moved when this share of its returns did."""
ONWARD_M = 1.0
"""escape_goal(onward=True): how far on from the escape's end the way towards the target
must be free."""


def moved_into_frame(points: np.ndarray, v: float, w: float, dt_s: float) -> np.ndarray:
    """``points`` of the frame before, in the frame of the base after driving the arc (v, w)
    for ``dt_s`` (the exact arc, then the shared SE(2) change of frame)."""
    th = w * dt_s
    if abs(w) > 1e-9:
        dx, dy = v / w * math.sin(th), v / w * (1.0 - math.cos(th))
    else:
        dx, dy = v * dt_s, 0.0
    return transform_points(points, (0.0, 0.0, 0.0), (dx, dy, th))


class ScanView(NamedTuple):
    """What part of the base's surroundings one scan covers: bearings ``lo_rad`` to ``hi_rad``
    (from the base's +x) seen from the laser at (``x_m``, ``y_m``) in the base frame."""

    x_m: float
    y_m: float
    lo_rad: float
    hi_rad: float


def scan_view(scan: LaserScan, mount: LaserMount | None = None) -> ScanView:
    """The :class:`ScanView` of ``scan``'s beams, the laser at ``mount`` (None: the base's
    origin, looking along +x)."""
    mount = mount or LaserMount()
    first = float(scan.angle_min_rad)
    last = first + float(scan.angle_increment_rad) * max(len(scan.ranges) - 1, 0)
    yaw = mount.yaw_rad
    return ScanView(mount.x_m, mount.y_m, min(first, last) + yaw, max(first, last) + yaw)


def scan_points(scan: LaserScan, mount: LaserMount | None = None) -> np.ndarray:
    """(N, 2) base-frame points of ``scan``'s returns (no return -- NaN, inf, 0, out of
    range -- as laser_legs' ``valid_mask`` says), the laser at ``mount`` (None: the base's
    origin)."""
    r = scan.ranges_m()
    n = r.shape[0]
    valid = valid_mask(r, scan.range_min_m, scan.range_max_m)
    _, cos, sin = beam_geometry(float(scan.angle_min_rad), float(scan.angle_increment_rad), n)
    r = r[valid].astype(np.float64)
    points = np.column_stack([r * cos[:n][valid], r * sin[:n][valid]])
    if mount is None or mount.is_identity:
        return points
    return mount.to_base(points)


class ObstacleGuard:
    """The guard of the module doc for one base; :meth:`apply` is a pure function of its
    arguments."""

    def __init__(
        self,
        *,
        body_radius_m: float,
        margin_m: float,
        horizon_s: float,
        decel_mps2: float,
        max_turn_radps: float,
        turn_candidates: int,
        min_speed_mps: float,
        ignore_near_target_m: float,
        min_progress: float = 0.5,
        between_m: float = 0.25,
        wait_moving_only: bool = True,
        step_m: float = 0.05,
        escape_m: float = 0.0,
        escape_clear_m: float = 0.01,
        escape_slack_rad: float = math.radians(15.0),
        escape_headings: int = 37,
    ) -> None:
        if turn_candidates < 2:
            raise ValueError("turn_candidates must be >= 2")
        self.radius = body_radius_m + margin_m
        self.between_m = between_m
        self.wait_moving_only = wait_moving_only
        self.horizon = horizon_s
        self.decel = decel_mps2
        self.min_speed = min_speed_mps
        self.ignore = ignore_near_target_m
        self.step = step_m
        self.min_progress = min_progress
        self.turns = np.linspace(-max_turn_radps, max_turn_radps, turn_candidates)
        self.max_turn = max_turn_radps
        self.escape_m = escape_m
        self.escape_clear = body_radius_m + escape_clear_m
        self.escape_slack = escape_slack_rad
        if escape_headings < 3:
            raise ValueError("escape_headings must be >= 3")
        # escape_m: headings -90..90 deg, one every 5 deg by default
        self.headings = np.linspace(-math.pi / 2, math.pi / 2, escape_headings)

    def reach_m(self, v: float) -> float:
        """L: the horizon's travel plus the braking distance at speed ``v``."""
        return v * self.horizon + v * v / (2.0 * self.decel)

    def speed_for(self, free_m: float) -> float:
        """The speed whose reach is ``free_m``."""
        h, b = self.horizon, self.decel
        return max(0.0, b * (-h + math.sqrt(h * h + 2.0 * max(free_m, 0.0) / b)))

    def _arcs(self, v: float, turns: np.ndarray, length: float):
        """Sample poses (C, K) x, y along each arc (v, w), and the arc lengths s (K,)."""
        k = max(1, math.ceil(length / self.step))
        s = np.linspace(length / k, length, k)  # (K,)
        kappa = turns / v  # (C,)
        ks = kappa[:, None] * s[None, :]  # (C, K)
        straight = np.abs(kappa) < 1e-9
        safe = np.where(straight, 1.0, kappa)[:, None]
        x = np.where(straight[:, None], s[None, :], np.sin(ks) / safe)
        y = np.where(straight[:, None], 0.0, (1.0 - np.cos(ks)) / safe)
        return x, y, s

    def free_lengths(
        self,
        v: float,
        turns: np.ndarray,
        points: np.ndarray,
        length: float,
        radius: float | None = None,
    ):
        """Free length (m, at most ``length``) along each arc (v, w) for w in ``turns``, for a
        disc of ``radius`` (default: the body and the margin)."""
        radius = self.radius if radius is None else radius
        free = np.full(turns.shape, length)
        if points.shape[0] == 0 or v <= 0.0:
            return free
        x, y, s = self._arcs(v, turns, length)
        dx = x[:, :, None] - points[None, None, :, 0]
        dy = y[:, :, None] - points[None, None, :, 1]
        thr = self.thresholds(points, radius)
        hit = (dx * dx + dy * dy < (thr * thr)[None, None, :]).any(axis=2)  # (C, K)
        first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
        return np.where(first < 0, length, np.where(first > 0, s[np.maximum(first - 1, 0)], 0.0))

    @staticmethod
    def thresholds(points: np.ndarray, radius: float) -> np.ndarray:
        """(N,) how near each point a path may bring the base's centre: ``radius``, or, when
        the base is nearer than that already, as near as the nearest return is (the base
        beside a wall may drive along it)."""
        r = np.hypot(points[:, 0], points[:, 1])
        start = float(r.min()) if r.shape[0] else math.inf
        return np.full(r.shape, min(radius, start - 1e-3))

    def _reachable(
        self, points: np.ndarray, target_xy: tuple[float, float] | None, length: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The points that are not the target's legs, and of those the ones the disc can
        reach along an arc of ``length``."""
        keep = np.ones(points.shape[0], dtype=bool)
        if target_xy is not None and self.ignore > 0.0:
            keep = np.hypot(points[:, 0] - target_xy[0], points[:, 1] - target_xy[1]) > self.ignore
        seen = points[keep]
        near = np.hypot(seen[:, 0], seen[:, 1]) <= length + self.radius + self.step
        return seen, seen[near]

    def progress(self, v: float, turns: np.ndarray, length: float, target_xy) -> np.ndarray:
        """How much nearer the target each arc's end lies than the base does now (m)."""
        x, y, _ = self._arcs(v, turns, length)
        tx, ty = target_xy
        return math.hypot(tx, ty) - np.hypot(tx - x[:, -1], ty - y[:, -1])

    def blocked(
        self,
        v: float,
        w: float,
        points: np.ndarray,
        target_xy: tuple[float, float] | None,
    ) -> bool:
        """The arc (v, w) -- the command the base will execute, after the limits -- brings
        the body within escape_clear_m of a return within its reach, or nearer when it is
        nearer already (the check :meth:`apply` makes of the goal's arc, without the margin:
        a contact, not comfort; returns near the target are its legs)."""
        if v <= 0.0 or points.shape[0] == 0:
            return False
        length = self.reach_m(v)
        _, pts = self._reachable(points, target_xy, length)
        if pts.shape[0] == 0:
            return False
        free = self.free_lengths(v, np.array([w]), pts, length, self.escape_clear)
        return float(free[0]) < length

    def apply(
        self,
        v: float,
        w: float,
        points: np.ndarray,
        target_xy: tuple[float, float] | None,
        may_swerve: bool = True,
        previous: np.ndarray | None = None,
        may_escape: bool = True,
    ) -> tuple[float, float, str | None]:
        """(v, w, reason) for the command (v, w) and the scan's base-frame ``points``;
        reason None: unchanged. ``may_swerve`` False: something on the line to the target
        is waited for (reason ``avoid_wait``) rather than gone round; ``previous``: the scan
        before, moved into this scan's frame -- then only something that moved is waited
        for (``wait_moving_only``); ``may_escape`` False: stopped, it stands (the controller
        lets the escape start only after guard.escape_after_s)."""
        if v <= 0.0 or points.shape[0] == 0:
            return v, w, None
        length = self.reach_m(v)
        # only what the disc can reach along any arc of this length
        seen, pts = self._reachable(points, target_xy, length)
        if pts.shape[0] == 0:
            return v, w, None
        own = float(self.free_lengths(v, np.array([w]), pts, length)[0])
        if own >= length:
            return v, w, None
        if not may_swerve and target_xy is not None and self._between(pts, target_xy, previous):
            return self._slow(v, w, own, "avoid_wait")
        free = self.free_lengths(v, self.turns, pts, length)
        ok = free >= length
        if target_xy is not None:  # a way round must still lead towards the target
            p0 = float(self.progress(v, np.array([w]), length, target_xy)[0])
            ok &= self.progress(v, self.turns, length, target_xy) >= (
                self.min_progress * p0 if p0 > 0.0 else p0
            )
        if ok.any():
            cand = np.where(ok)[0]
            best = cand[np.argmin(np.abs(self.turns[cand] - w))]
            return v, float(self.turns[best]), "avoid_turn"
        out = self._slow(v, w, own, "avoid_slow")
        if out[2] == "avoid_stop" and may_escape and self.escape_m > 0.0 and target_xy is not None:
            return self._escape(v, seen, target_xy) or out
        return out

    def free_headings(self, points: np.ndarray) -> np.ndarray:
        """Of ``headings``, those along which a straight run of escape_m keeps the body
        ``escape_clear_m`` clear of every point (or, when it is nearer already, comes no
        nearer)."""
        return self._runs_free(points, self.headings, self.escape_m)

    def _runs_free(self, points: np.ndarray, headings: np.ndarray, d_run: float) -> np.ndarray:
        """Of ``headings``, those along which a straight run of ``d_run`` from the base keeps
        the body escape_clear_m clear of every point (:meth:`free_headings`)."""
        near = np.hypot(points[:, 0], points[:, 1]) <= d_run + self.escape_clear
        pts = points[near]
        if pts.shape[0] == 0:
            return np.ones(headings.shape, dtype=bool)
        ux, uy = np.cos(headings)[:, None], np.sin(headings)[:, None]
        # each point's distance to each straight run (a segment from the base, d_run long)
        t = np.clip(ux * pts[None, :, 0] + uy * pts[None, :, 1], 0.0, d_run)  # (H, N)
        d = np.hypot(pts[None, :, 0] - t * ux, pts[None, :, 1] - t * uy)
        # already nearer than escape_clear_m: no closing in further (as for the arcs)
        thr = self.thresholds(pts, self.escape_clear)
        return ~(d < thr[None, :]).any(axis=1)

    def escape_goal(
        self,
        points: np.ndarray,
        target_xy: tuple[float, float],
        onward: bool = False,
        keep_in_view: tuple[float, float] | None = None,
    ) -> tuple[float, float] | None:
        """The escape's end point in the base frame, escape_m along the free heading nearest
        the target's bearing (straight ahead when that is free and within escape_slack of
        it), or None (no free heading within 90 deg of the target's bearing). Returns within
        ignore_near_target_m of the target are its legs. ``onward``: first the shortest run
        (escape_m, 1.5 escape_m, 2 escape_m), then the heading nearest the target's bearing,
        whose end leaves the straight way on towards the target free for the body and the
        margin (up to ONWARD_M, short of its legs) -- the point past the corner, not merely
        away from it; none such: as without. ``keep_in_view`` (lo, hi): only headings that
        leave the target's bearing within (lo, hi) of the base's heading once it faces them
        (the laser's view, :class:`ScanView`, its offset from the base's origin neglected)."""
        keep = np.hypot(points[:, 0] - target_xy[0], points[:, 1] - target_xy[1]) > self.ignore
        points = points[keep]
        bearing = math.atan2(target_xy[1], target_xy[0])
        off = np.abs(np.angle(np.exp(1j * (self.headings - bearing))))
        toward = off <= math.pi / 2
        if keep_in_view is not None:
            rel = np.angle(np.exp(1j * (bearing - self.headings)))
            toward &= (rel >= keep_in_view[0]) & (rel <= keep_in_view[1])
        free = self.free_headings(points)  # escape_m runs
        if onward:
            for k in (1.0, 1.5, 2.0):
                d_run = k * self.escape_m
                ok = toward & (free if k == 1.0 else self._runs_free(points, self.headings, d_run))
                if not ok.any():
                    continue
                cand = np.where(ok)[0]
                cand = cand[np.argsort(off[cand], kind="stable")]
                ends = d_run * np.column_stack(
                    [np.cos(self.headings[cand]), np.sin(self.headings[cand])]
                )
                clear = self._onward_free(points, ends, target_xy)
                if clear.any():
                    end = ends[int(np.argmax(clear))]
                    return float(end[0]), float(end[1])
        ok = free & toward
        if not ok.any():
            return None
        cand = np.where(ok)[0]
        best = cand[np.argmin(off[cand])]
        ahead = int(np.argmin(np.abs(self.headings)))
        phi = 0.0
        if not (ok[ahead] and off[ahead] <= off[best] + self.escape_slack):
            phi = float(self.headings[best])
        return self.escape_m * math.cos(phi), self.escape_m * math.sin(phi)

    def _onward_free(
        self,
        points: np.ndarray,
        ends: np.ndarray,
        target_xy: tuple[float, float],
    ) -> np.ndarray:
        """(E,) for each end point (E, 2): the straight way from it towards the target, up
        to ONWARD_M and short of the target's legs (ignore_near_target_m), keeps the body and
        the margin off every point."""
        to = np.asarray(target_xy, dtype=float)[None, :] - ends  # (E, 2)
        dist = np.hypot(to[:, 0], to[:, 1])
        run = np.clip(np.minimum(dist - self.ignore, ONWARD_M), 0.0, None)
        u = to / np.maximum(dist, 1e-9)[:, None]
        if points.shape[0] == 0:
            return np.ones(ends.shape[0], dtype=bool)
        rel = points[None, :, :] - ends[:, None, :]  # (E, N, 2)
        t = np.clip((rel * u[:, None, :]).sum(axis=2), 0.0, run[:, None])
        d = np.hypot(rel[:, :, 0] - t * u[:, None, 0], rel[:, :, 1] - t * u[:, None, 1])
        return ~(d < self.radius).any(axis=1)

    def toward_goal(
        self,
        v: float,
        goal: tuple[float, float],
        points: np.ndarray,
        reached_m: float = 0.03,
        aligned_rad: float = math.radians(5.0),
    ) -> tuple[float, float, str] | None:
        """One step of the escape to ``goal`` (base frame): turn on the spot until it lies
        within ``aligned_rad`` of ahead, then drive there (at most ``v``, at the speed that
        stops at the goal, steering onto it) -- (v, w, "avoid_escape"); None when it is
        within ``reached_m`` or the straight run there is no longer free."""
        gx, gy = goal
        dist = math.hypot(gx, gy)
        if dist <= reached_m:
            return None
        phi = math.atan2(gy, gx)
        if abs(phi) > aligned_rad:
            w = min(self.max_turn, 4.0 * abs(phi) / self.horizon)
            return 0.0, math.copysign(w, phi), "avoid_escape"
        if points.shape[0] and not self._runs_free(points, np.array([phi]), dist)[0]:
            return None
        # the escape's own speed (what stops within escape_m), braking to stop at the goal
        speed = min(v, self.speed_for(self.escape_m), math.sqrt(2.0 * self.decel * dist))
        # pure pursuit onto the goal: curvature 2 sin(phi) / dist
        return speed, speed * 2.0 * math.sin(phi) / dist, "avoid_escape"

    def _escape(
        self,
        v: float,
        points: np.ndarray,
        target_xy: tuple[float, float],
    ) -> tuple[float, float, str] | None:
        """The escape of the module doc, recomputed from this pose: (v, w, "avoid_escape"),
        or None (no free heading within 90 deg of the target's bearing)."""
        goal = self.escape_goal(points, target_xy)
        if goal is None:
            return None
        return self.toward_goal(v, goal, points, aligned_rad=0.0)

    def _slow(self, v: float, w: float, own: float, reason: str) -> tuple[float, float, str]:
        """The command's own arc, at the speed that stops within its free length ``own``."""
        slow = min(v, self.speed_for(own))
        if slow < self.min_speed:
            return 0.0, w, "avoid_stop" if reason == "avoid_slow" else reason
        return slow, w * slow / v, reason  # the same arc, slower

    def _between(
        self, pts: np.ndarray, target_xy: tuple[float, float], previous: np.ndarray | None
    ) -> bool:
        """Something lies on the line from the base to the target (within ``between_m`` of
        it, short of the target) -- and, with ``previous`` and wait_moving_only, it moved:
        at least MOVED_SHARE of those returns lie more than MOVED_M from every return of the
        scan before (a wall, a box or a pillar stays where it was; a walker's legs do not)."""
        tx, ty = target_xy
        r = math.hypot(tx, ty)
        if r <= 0.0:
            return False
        along = (pts[:, 0] * tx + pts[:, 1] * ty) / r
        across = np.abs(pts[:, 1] * tx - pts[:, 0] * ty) / r
        on = pts[(along > 0.0) & (along < r) & (across < self.between_m)]
        if on.shape[0] == 0:
            return False
        if not self.wait_moving_only or previous is None or previous.shape[0] == 0:
            return True
        d = np.hypot(on[:, None, 0] - previous[None, :, 0], on[:, None, 1] - previous[None, :, 1])
        return bool(np.mean(d.min(axis=1) > MOVED_M) >= MOVED_SHARE)
