"""Static background from a scan stream: where a point was seen occupied, again and again, over
the last seconds (no labels; beyond the seeds).

The standard trick of ROS leg trackers (leg_tracker's local occupancy grid): furniture, posts and
clutter stay put, a walking person's legs do not. :class:`StaticBackground` keeps the recent
scans of one stream and, for any point of the newest scan, counts in how many of them the laser
looked at that point (a *view*) and found something there (a *hit*).

Ego-motion. When the caller knows the laser's pose at a scan's stamp (``update(..., pose=)``:
the robot's odometry composed with the laser's mount, from wheel odometry or the
laser_odometry service), the scan is placed there: no matching. Without it (the leg_tracker
bags hold no odometry or tf, and the robot moves in ``negative_2``: ~0.6 m/s, ~15°/s, 60-70 %
of the beams change by > 5 cm from one scan to the next) the scans are registered to each
other (``ego_motion=True``): each scan is matched to the previous one by projective
point-to-line ICP (services/common/scanmatch.py, shared with laser_odometry),
starting from a constant-velocity guess. Poses are chained into an odometry frame that starts at
the stream's first scan -- or, once poses are given, into their frame: a scan without a pose
between two with one is matched and chained onto the last pose (the frame of the history
changes from the chained one to the given one only by a reset). Too few inliers means the
match failed: the history is cleared (a wrong pose would mark people static).
``ego_motion=False`` takes a scan without a pose as seen from where the previous one was (a
still laser: the history is then a per-beam range history in the laser frame).

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

#: Offsets of the beams before, at and after a beam on the padded range rows.
_WINDOW = np.arange(3)


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
        self.given_poses = 0
        """Scans placed at a given pose, without matching (for health notes and tests)."""
        self._key: tuple | None = None
        self._clear()

    def _clear(self) -> None:
        # (max_scans, n + 2): the ranges of beam -1 .. n, NaN where no return (and on the pads)
        self._ranges: np.ndarray | None = None
        self._poses = np.zeros((self.max_scans, 3))
        self._rot = np.zeros((self.max_scans, 2))  # cos, -sin of each pose's heading
        self._stamps = np.zeros(self.max_scans, dtype=np.int64)
        self._count = 0
        self._head = 0  # next slot of the ring
        self._prev: ScanFrame | None = None
        self._prev_stamp: int | None = None
        self._ref_stamp: int | None = None  # the stamp of self._prev
        self._pose = np.zeros(3)
        self._velocity = np.zeros(3)  # last increment per ns (constant-velocity guess)
        self._anchored = False  # the history's poses are in the given poses' frame

    def reset(self) -> None:
        """Forget everything (a new stream)."""
        self._key = None
        self._clear()

    @property
    def pose(self) -> np.ndarray:
        """(x, y, θ) of the last scan given to :meth:`update` in the odometry frame: that of
        the given poses, else one that starts afresh, at zero, with every new history (watch
        :attr:`resets`). Zero when the laser is taken as still (``ego_motion=False``, no
        poses)."""
        return self._pose.copy()

    def update(
        self, scan: LaserScan, x: np.ndarray, y: np.ndarray, pose=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Register ``scan`` and return (hits, views) of the points (x, y) in its frame, counted
        over the remembered earlier scans; then remember ``scan``. ``pose``: the laser's
        (x, y, θ) in an odometry frame at the scan's stamp, when known (then no matching).
        Never raises on bad beams."""
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
        frame = ScanFrame(raw, ok, cos[:n], sin[:n])
        still = False
        if pose is not None and all(math.isfinite(v) for v in pose):
            self._given(np.array(pose, dtype=np.float64), stamp)
            self.given_poses += 1
        elif self._prev is not None and self.ego_motion and inc != 0.0:
            still = self._match(frame, stamp, key)
        hits, views = self._query(np.asarray(x, np.float64), np.asarray(y, np.float64), stamp, scan)
        self._remember(frame, stamp, n, still)
        return hits, views

    def _given(self, pose: np.ndarray, stamp: int) -> None:
        """Place the scan at the given ``pose``. A history chained from a zero start (scans
        without poses so far) is in another frame: it is started afresh."""
        if not self._anchored and self._count:
            self.resets += 1
            key = self._key
            self._clear()
            self._key = key
        if self._prev is not None and self._ref_stamp is not None and stamp > self._ref_stamp:
            # the step from the last registered scan, for the constant-velocity guess of a
            # later scan without a pose
            c, s_ = math.cos(self._pose[2]), math.sin(self._pose[2])
            dx, dy = pose[0] - self._pose[0], pose[1] - self._pose[1]
            step = np.array([c * dx + s_ * dy, -s_ * dx + c * dy, pose[2] - self._pose[2]])
            self._velocity = step / (stamp - self._ref_stamp)
        self._pose = pose
        self._anchored = True

    def _match(self, frame: ScanFrame, stamp: int, key: tuple) -> bool:
        """Register the scan on the last one by ICP (module docstring); True when the laser
        was still and no match was needed. A failed match clears the history."""
        dt = stamp - (self._ref_stamp or stamp)
        guess = self._velocity * dt
        # nothing moved since the scan last matched: no match needed (~300 us saved); that
        # scan stays the one the next is matched to, so a slow drift is caught up later
        still = self._still(frame, guess)
        if still:
            step, frac = np.zeros(3), 1.0
        else:
            amin, inc = key[1], key[2]
            step, frac = match_scans(self._prev, frame, amin, inc, guess, stride=self.icp_stride)
        if frac < self.min_inliers or not np.all(np.isfinite(step)):
            self.resets += 1
            self._clear()
            self._key = key
        else:
            self._pose = compose(self._pose, step)
            self._velocity = step / dt if dt > 0 else np.zeros(3)
        return still

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
            self._ranges = np.full((self.max_scans, n + 2), np.nan)
        if self._count:  # thin a fast scanner's scans to memory / max_scans apart
            last = self._stamps[(self._head - 1) % self.max_scans]
            if stamp - last < self.memory_ns // self.max_scans:
                return
        self._ranges[self._head, 1:-1] = frame.r
        self._poses[self._head] = self._pose
        self._rot[self._head] = math.cos(self._pose[2]), -math.sin(self._pose[2])
        self._stamps[self._head] = stamp
        self._head = (self._head + 1) % self.max_scans
        self._count = min(self._count + 1, self.max_scans)

    def _query(self, x: np.ndarray, y: np.ndarray, stamp: int, scan: LaserScan):
        k = x.shape[0]
        zero = np.zeros(k, dtype=np.intp)
        m = self._count
        if m == 0 or k == 0 or self._ranges is None:
            return zero, zero
        recent = self._stamps[:m] >= stamp - self.memory_ns
        if recent.all():  # (the usual case: no copies)
            R, P, rot = self._ranges[:m], self._poses[:m], self._rot[:m]
        else:
            slots = np.flatnonzero(recent)
            if slots.shape[0] == 0:
                return zero, zero
            R, P, rot = self._ranges[slots], self._poses[slots], self._rot[slots]
        n = R.shape[1] - 2
        finite = np.isfinite(x + y)  # a non-finite point is never background
        if not finite.all():
            x, y = np.where(finite, x, 0.0), np.where(finite, y, 0.0)
        c, s = math.cos(self._pose[2]), math.sin(self._pose[2])
        wx = c * x - s * y + self._pose[0]  # the points in the odometry frame
        wy = s * x + c * y + self._pose[1]
        ci, nsi = rot[:, 0:1], rot[:, 1:2]
        dx = wx - P[:, 0:1]
        dy = wy - P[:, 1:2]
        lx = ci * dx - nsi * dy  # ... in each remembered scan's frame (m, k)
        ly = nsi * dx + ci * dy
        rho = np.hypot(lx, ly)
        b = beam_index(
            np.arctan2(ly, lx), float(scan.angle_min_rad), float(scan.angle_increment_rad), n
        )
        seen = (b >= 0) & (rho >= scan.range_min_m) & (rho <= scan.range_max_m)
        # the beams b - 1, b, b + 1 of each remembered scan: b .. b + 2 on the padded rows
        b += np.arange(R.shape[0])[:, None] * (n + 2)
        r = R.reshape(-1).take(b[:, :, None] + _WINDOW)  # (m, k, 3), NaN where no return
        with np.errstate(invalid="ignore"):
            near = np.abs(r - rho[:, :, None]) <= self.hit_m
            hit = seen & near.any(axis=2)
            free = seen & ~hit & (r[:, :, 1] > rho + self.hit_m)
        hits = hit.sum(axis=0) * finite
        return hits, hits + free.sum(axis=0) * finite

    @staticmethod
    def static_mask(
        hits: np.ndarray, views: np.ndarray, static_fraction: float, min_views: int
    ) -> np.ndarray:
        """True where a point counts as static background."""
        return (views >= min_views) & (hits >= static_fraction * views)
