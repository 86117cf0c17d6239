"""The laser's motion from its scans: each scan matched against a keyframe (no Zenoh here).

:class:`ScanOdometry` keeps the laser's pose ``L`` in an odometry frame that is the laser frame
of the first scan. A new scan is matched (services/common/scanmatch.py) against the keyframe,
an earlier scan whose pose ``K`` is known, starting from the constant-velocity prediction::

    guess = K⁻¹ ∘ (L_prev ∘ v·dt)          the new scan in the keyframe's frame
    step  = ICP(keyframe, scan, guess)      refined
    L     = K ∘ step

Matching against a keyframe rather than the previous scan keeps a still laser still (the
matching noise does not add up scan after scan) and slows the drift of a moving one. The
scan becomes the next keyframe when it is ``keyframe_distance_m`` or ``keyframe_angle_deg``
away from the keyframe, or matched it with fewer than ``keyframe_min_inliers``.

A match with fewer than ``match.min_inliers`` inliers is tried again from the guess turned by
each of ``match.recovery_turns_deg`` either way, and from no motion and it turned (the best
kept); if all fail, the match failed:
counted, the pose carried on along the last matched twist for at most ``carry_twist_s`` after
the last good match (then held), and the scan becomes the keyframe at that pose. A scan with
fewer than ``match.min_points`` valid returns (NaN, ±inf, out of its limits, empty) is refused
the same way (counted). A scan of another geometry or frame starts a new keyframe at the pose
reached (counted as a reset); nothing here raises on bad input.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from followbot.schemas import LaserScan
from followbot.services.common.scan import beam_geometry, valid_mask
from followbot.services.common.scanmatch import ScanFrame, compose, invert, match_scans

from .settings import LaserOdometrySettings

__all__ = ["COUNTS", "ScanOdometry", "Update"]

#: What :attr:`ScanOdometry.counts` counts: scans seen, matched, of which recovered by a turned
#: guess, failed matches, refused scans, keyframes taken, resets (another scan geometry).
COUNTS = ("scans", "matched", "recovered", "failed", "refused", "keyframes", "resets")


@dataclass(frozen=True)
class Update:
    """What one scan did: ``status`` is ``keyframe`` (nothing to match it with: the first scan,
    or the first after a refused one or another geometry), ``matched``, ``failed`` or
    ``refused``; ``pose`` the laser's (x, y, θ) in the odometry frame; ``inliers`` the match's
    inlier share (0 without a match)."""

    status: str
    pose: tuple[float, float, float]
    inliers: float = 0.0


class ScanOdometry:
    """Laser poses from a stream of scans (module docstring)."""

    def __init__(self, settings: LaserOdometrySettings) -> None:
        self.s = settings
        self.counts: Counter = Counter(dict.fromkeys(COUNTS, 0))
        self.reset()

    def reset(self) -> None:
        """Start again at zero (a new stream: the source restarted)."""
        self.pose = np.zeros(3)
        self._geometry: tuple | None = None
        self._keyframe: ScanFrame | None = None
        self._key_pose = np.zeros(3)
        self._stamp: int | None = None  # of the last scan handled
        self._good_stamp: int | None = None  # of the last good match
        # laser-frame increment per second at the last good match: the next match's guess
        self._velocity = np.zeros(3)

    def update(self, scan: LaserScan) -> Update:
        """Take ``scan`` (stamps increasing) and return where the laser is now."""
        self.counts["scans"] += 1
        stamp = int(scan.stamp_ns)
        dt = (stamp - self._stamp) / 1e9 if self._stamp is not None else 0.0
        if dt < 0:  # an older stamp: nothing to learn from it, the pose stays
            self.counts["refused"] += 1
            return Update("refused", self._pose_tuple())
        self._stamp = stamp
        frame, geometry = _frame(scan, self.s.match.normal_max_chord_m)
        if frame is None or int(np.count_nonzero(frame.ok)) < self.s.match.min_points:
            self.counts["refused"] += 1
            self._coast(dt, stamp)
            self._keyframe = None  # the next good scan starts a keyframe where the pose is
            return Update("refused", self._pose_tuple())
        if self._geometry is not None and geometry != self._geometry:
            self.counts["resets"] += 1  # another laser or setup: nothing to match it with
            self._coast(dt, stamp)
            self._keyframe = None
        if self._keyframe is None:
            self._take_keyframe(frame, geometry)
            return Update("keyframe", self._pose_tuple())
        return self._match(frame, geometry, dt, stamp)

    def _match(self, frame: ScanFrame, geometry: tuple, dt: float, stamp: int) -> Update:
        gap = dt > self.s.max_gap_s
        to_key = invert(self._key_pose)
        still = compose(to_key, self.pose)  # the laser has not moved since the last scan
        moved = still if gap else compose(to_key, compose(self.pose, self._velocity * dt))
        step, frac, recovered = self._icp(self._keyframe, frame, geometry, moved, still)
        if frac < self.s.match.min_inliers:
            self.counts["failed"] += 1
            self._coast(dt, stamp)
            self._take_keyframe(frame, geometry)
            return Update("failed", self._pose_tuple(), frac)
        pose = compose(self._key_pose, step)
        if dt > 0 and not gap:
            self._velocity = compose(invert(self.pose), pose) / dt
        elif gap:
            self._velocity = np.zeros(3)
        self.pose = pose
        self._good_stamp = stamp
        self.counts["matched"] += 1
        self.counts["recovered"] += recovered
        if (
            math.hypot(step[0], step[1]) > self.s.keyframe_distance_m
            or abs(step[2]) > math.radians(self.s.keyframe_angle_deg)
            or frac < self.s.keyframe_min_inliers
        ):
            self._take_keyframe(frame, geometry)
        return Update("matched", self._pose_tuple(), frac)

    def _icp(self, ref: ScanFrame, cur: ScanFrame, geometry: tuple, moved, still):
        """(step, inlier share, whether a second guess found it): from the constant-velocity
        guess ``moved``; when that fails, from it and from ``still`` turned either way by each
        recovery turn, and from ``still`` itself, the best kept."""
        m = self.s.match
        _, amin, inc, _ = geometry
        kw = {"stride": m.stride, "iterations": m.iterations, "max_distance_m": m.max_distance_m}
        step, frac = match_scans(ref, cur, amin, inc, moved, **kw)
        if frac >= m.min_inliers or not m.recovery_turns_deg:
            return step, frac, False
        best = (step, frac, False)
        turns = [math.radians(sign * t) for t in m.recovery_turns_deg for sign in (1.0, -1.0)]
        guesses = [moved + np.array([0.0, 0.0, t]) for t in turns] + [still]
        guesses += [still + np.array([0.0, 0.0, t]) for t in turns]
        for g in guesses:
            s2, f2 = match_scans(ref, cur, amin, inc, g, **kw)
            if f2 > best[1] and np.all(np.isfinite(s2)):
                best = (s2, f2, True)
        return best

    def _coast(self, dt: float, stamp: int) -> None:
        """No match: carry the pose on along the last twist, or hold it (module docstring)."""
        carry = (
            self._good_stamp is not None
            and dt <= self.s.max_gap_s
            and (stamp - self._good_stamp) / 1e9 <= self.s.carry_twist_s
        )
        if carry:
            self.pose = compose(self.pose, self._velocity * dt)

    def _take_keyframe(self, frame: ScanFrame, geometry: tuple) -> None:
        self._keyframe, self._geometry = frame, geometry
        self._key_pose = self.pose.copy()
        self.counts["keyframes"] += 1

    def _pose_tuple(self) -> tuple[float, float, float]:
        x, y, th = (float(v) for v in self.pose)
        return x, y, math.remainder(th, math.tau)


def _frame(scan: LaserScan, max_chord_m: float) -> tuple[ScanFrame | None, tuple]:
    """The scan's points and normals, and its geometry (beams, first angle, step, frame)."""
    raw = np.asarray(scan.ranges_m(), dtype=np.float64)
    n = raw.shape[0]
    amin, inc = float(scan.angle_min_rad), float(scan.angle_increment_rad)
    geometry = (n, amin, inc, scan.frame_id)
    if n == 0 or inc == 0.0:
        return None, geometry
    ok = valid_mask(raw, scan.range_min_m, scan.range_max_m) & np.isfinite(raw)
    _, cos, sin = beam_geometry(amin, inc, n)
    return ScanFrame(np.where(ok, raw, 0.0), ok, cos[:n], sin[:n], max_chord_m), geometry
