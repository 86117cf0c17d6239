"""Static background from a scan stream: where a point was seen occupied, again and again, over
the last seconds (no labels; beyond the seeds).

The standard trick of ROS leg trackers (leg_tracker's local occupancy grid): furniture, posts and
clutter stay put, a walking person's legs do not. :class:`StaticBackground` keeps the recent
scans of one stream and, for any point of the newest scan, counts in how many of them the laser
looked at that point (a *view*) and found something there (a *hit*).

Ego-motion. The leg_tracker bags hold no odometry or tf, and the robot moves in ``negative_2``
(~0.6 m/s, ~15°/s: 60-70 % of the beams change by > 5 cm from one scan to the next), so the
scans are registered to each other (``ego_motion=True``): each scan is matched to the previous
one by projective point-to-line ICP (services/common/scanmatch.py, shared with laser_odometry),
starting from a constant-velocity guess. Poses are chained into an odometry frame that starts at
the stream's first scan. Too few inliers means the match failed: the history is cleared (a
wrong pose would mark people static). ``ego_motion=False`` takes the laser as still (the
history is then a per-beam range history in the laser frame).

Query. A point ``c`` of the newest scan is moved into the frame of each remembered scan ``i``
(``p = T_i⁻¹ T_now c``, all scans and points at once); with ``ρ``, ``φ`` its range and bearing
there and ``r`` the ranges of the beams ``φ`` falls on (± 1 beam)::

    hit   if  min |r − ρ| ≤ hit_m                something was there
    free  if  not hit and r_centre > ρ + hit_m   the beam passed through the point
    views = hits + frees                         (occluded, out of view or no return: unknown)

A point is *static* when ``views ≥ min_views`` and ``hits ≥ static_fraction · views``. A person
standing still for the whole memory is static too: that is the price (measured in
``docs/laser_legs.md``).

Resets: a scan of another size, geometry or ``frame_id``, a stamp going backwards, a gap longer
than the memory, or a failed match start a new history. NaN, ±inf and out-of-bounds beams are
"no return" everywhere. Cost: bounded by ``max_scans`` remembered scans (a fast scanner's scans
are thinned to ``memory_s / max_scans`` apart) and by ``icp_stride`` (every k-th beam is
matched).
"""

from __future__ import annotations

import math

import numpy as np

from followbot.schemas import LaserScan
from followbot.services.common.scan import beam_geometry, valid_mask
from followbot.services.common.scanmatch import ScanFrame, beam_index, compose, match_scans

__all__ = ["StaticBackground", "match_scans"]

#: A scan is taken as seen from where the previous one was, without matching, when the last
#: match left the laser still (a constant-velocity guess under these) and at most
#: STILL_FRACTION of the beams changed by more than STILL_CHANGE_M since the previous scan.
#: A choice (not tuned): 2 % of the beams over ~1 cm of noise, a few per cent for walkers.
STILL_GUESS_M = 0.01
STILL_GUESS_RAD = math.radians(0.2)
STILL_CHANGE_M = 0.05
STILL_FRACTION = 0.05


class StaticBackground:
    """Recent scans of one stream; counts hits and views of query points (module docstring).

    Parameters
    ----------
    memory_s: how far back scans are remembered (s), > 0.
    hit_m: a remembered beam within this of a point's range is a hit (m).
    ego_motion: register the scans to each other (True), or take the laser as still.
    max_scans: at most this many scans are remembered.
    min_inliers: a match with a smaller inlier share is a failure (history cleared).
    icp_stride: every k-th beam of the new scan is matched (cost against accuracy).
    """

    def __init__(
        self,
        memory_s: float,
        *,
        hit_m: float = 0.15,
        ego_motion: bool = True,
        max_scans: int = 40,
        min_inliers: float = 0.3,
        icp_stride: int = 4,
    ) -> None:
        if not memory_s > 0:
            raise ValueError("memory_s must be > 0")
        if not hit_m > 0:
            raise ValueError("hit_m must be > 0")
        if max_scans < 1:
            raise ValueError("max_scans must be >= 1")
        self.memory_ns = int(memory_s * 1e9)
        self.hit_m = float(hit_m)
        self.ego_motion = bool(ego_motion)
        self.max_scans = int(max_scans)
        self.min_inliers = float(min_inliers)
        self.icp_stride = int(icp_stride)
        self.resets = 0
        """How many times the history was started again (for health notes and tests)."""
        self._key: tuple | None = None
        self._clear()

    def _clear(self) -> None:
        self._ranges: np.ndarray | None = None  # (max_scans, n), NaN where no return
        self._poses = np.zeros((self.max_scans, 3))
        self._stamps = np.zeros(self.max_scans, dtype=np.int64)
        self._count = 0
        self._head = 0  # next slot of the ring
        self._prev: ScanFrame | None = None
        self._prev_stamp: int | None = None
        self._ref_stamp: int | None = None  # the stamp of self._prev
        self._pose = np.zeros(3)
        self._velocity = np.zeros(3)  # last increment per ns (constant-velocity guess)

    def reset(self) -> None:
        """Forget everything (a new stream)."""
        self._key = None
        self._clear()

    @property
    def pose(self) -> np.ndarray:
        """(x, y, θ) of the last scan given to :meth:`update` in the odometry frame (which
        starts afresh, at zero, with every new history: watch :attr:`resets`). Zero when the
        laser is taken as still (``ego_motion=False``)."""
        return self._pose.copy()

    def update(
        self, scan: LaserScan, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Register ``scan`` and return (hits, views) of the points (x, y) in its frame, counted
        over the remembered earlier scans; then remember ``scan``. Never raises on bad beams."""
        raw = np.asarray(scan.ranges_m(), dtype=np.float64)
        n = raw.shape[0]
        amin, inc = float(scan.angle_min_rad), float(scan.angle_increment_rad)
        key = (n, amin, inc, scan.frame_id)
        stamp = int(scan.stamp_ns)
        if key != self._key or inc == 0.0:
            if self._key is not None:
                self.resets += 1
            self._key = key
            self._clear()
        elif self._prev_stamp is not None and (
            stamp < self._prev_stamp or stamp - self._prev_stamp > self.memory_ns
        ):
            self.resets += 1
            self._clear()
        ok = valid_mask(raw, scan.range_min_m, scan.range_max_m) & np.isfinite(raw)
        _, cos, sin = beam_geometry(amin, inc, n)
        frame = ScanFrame(np.where(ok, raw, 0.0), ok, cos[:n], sin[:n])
        still = False
        if self._prev is not None and self.ego_motion and inc != 0.0:
            dt = stamp - (self._ref_stamp or stamp)
            guess = self._velocity * dt
            # nothing moved since the scan last matched: no match needed (~300 us saved); that
            # scan stays the one the next is matched to, so a slow drift is caught up later
            still = self._still(frame, guess)
            if still:
                step, frac = np.zeros(3), 1.0
            else:
                step, frac = match_scans(
                    self._prev, frame, amin, inc, guess, stride=self.icp_stride
                )
            if frac < self.min_inliers or not np.all(np.isfinite(step)):
                self.resets += 1
                self._clear()
                self._key = key
            else:
                self._pose = compose(self._pose, step)
                self._velocity = step / dt if dt > 0 else np.zeros(3)
        hits, views = self._query(np.asarray(x, np.float64), np.asarray(y, np.float64), stamp, scan)
        self._remember(frame, stamp, n, still)
        return hits, views

    def _still(self, frame: ScanFrame, guess: np.ndarray) -> bool:
        """True when the laser was still at the last match (its guess moves it by less than
        STILL_GUESS_M / STILL_GUESS_RAD) and at most STILL_FRACTION of the beams returning in
        both this scan and the last matched one changed by more than STILL_CHANGE_M (people
        walking past a still robot change a few per cent; a robot driving or turning, most)."""
        if abs(guess[0]) + abs(guess[1]) > STILL_GUESS_M or abs(guess[2]) > STILL_GUESS_RAD:
            return False
        prev = self._prev
        both = np.count_nonzero(frame.ok & prev.ok)
        with np.errstate(invalid="ignore"):  # NaN where a beam has no return: not changed
            changed = np.count_nonzero(np.abs(frame.r - prev.r) > STILL_CHANGE_M)
        return both >= 10 and changed <= STILL_FRACTION * both

    def _remember(self, frame: ScanFrame, stamp: int, n: int, still: bool = False) -> None:
        if not still:  # the scan the next one is matched to
            self._prev = frame
            self._ref_stamp = stamp
        self._prev_stamp = stamp
        if self._ranges is None:
            self._ranges = np.full((self.max_scans, n), np.nan)
        if self._count:  # thin a fast scanner's scans to memory / max_scans apart
            last = self._stamps[(self._head - 1) % self.max_scans]
            if stamp - last < self.memory_ns // self.max_scans:
                return
        self._ranges[self._head] = frame.r
        self._poses[self._head] = self._pose
        self._stamps[self._head] = stamp
        self._head = (self._head + 1) % self.max_scans
        self._count = min(self._count + 1, self.max_scans)

    def _query(self, x: np.ndarray, y: np.ndarray, stamp: int, scan: LaserScan):
        k = x.shape[0]
        zero = np.zeros(k, dtype=np.intp)
        if self._count == 0 or k == 0 or self._ranges is None:
            return zero, zero
        slots = np.flatnonzero(self._stamps[: self._count] >= stamp - self.memory_ns)
        if slots.shape[0] == 0:
            return zero, zero
        R = self._ranges[slots]  # (m, n)
        P = self._poses[slots]  # (m, 3)
        n = R.shape[1]
        finite = np.isfinite(x) & np.isfinite(y)  # a non-finite point is never background
        if not finite.all():
            x, y = np.where(finite, x, 0.0), np.where(finite, y, 0.0)
        c, s = math.cos(self._pose[2]), math.sin(self._pose[2])
        wx = c * x - s * y + self._pose[0]  # the points in the odometry frame
        wy = s * x + c * y + self._pose[1]
        ci, si = np.cos(P[:, 2])[:, None], np.sin(P[:, 2])[:, None]
        dx = wx[None, :] - P[:, 0:1]
        dy = wy[None, :] - P[:, 1:2]
        lx = ci * dx + si * dy  # ... in each remembered scan's frame (m, k)
        ly = -si * dx + ci * dy
        rho = np.hypot(lx, ly)
        b = beam_index(
            np.arctan2(ly, lx), float(scan.angle_min_rad), float(scan.angle_increment_rad), n
        )
        seen = (b >= 0) & (rho >= scan.range_min_m) & (rho <= scan.range_max_m)
        rows = np.arange(R.shape[0])[:, None, None]
        bw = np.clip(b[:, :, None] + np.array([-1, 0, 1]), 0, n - 1)
        r = R[rows, bw]  # (m, k, 3), NaN where no return
        with np.errstate(invalid="ignore"):
            near = np.abs(r - rho[:, :, None]) <= self.hit_m
            hit = seen & near.any(axis=2)
            free = seen & ~hit & (r[:, :, 1] > rho + self.hit_m)
        hits = np.count_nonzero(hit, axis=0) * finite
        return hits, hits + np.count_nonzero(free, axis=0) * finite

    @staticmethod
    def static_mask(
        hits: np.ndarray, views: np.ndarray, static_fraction: float, min_views: int
    ) -> np.ndarray:
        """True where a point counts as static background."""
        return (views >= min_views) & (hits >= static_fraction * views)
