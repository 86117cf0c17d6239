"""Re-taking by the laser a target the laser lost (``identity.laser_retake``).

Two rules, chosen by name (:data:`RETAKES`):

- ``near_loss`` (without vision only): the track nearest to where the target was lost, within
  ``identity.laser_reacquire_m``, walking at ``laser_reacquire_min_speed_mps`` or faster, at least
  ``laser_reacquire_min_range_m`` from the laser, within ``laser_reacquire_max_s`` of the loss.
- ``reach``: where the person could have walked since they were last seen. From the miss
  budget on (the target deleted, or coasting past ``max_misses`` under ``deleter:
  target_seconds``) the gate is centred where the target was last seen (its last update,
  carried by odometry), radius ``retake_gate_m + max(speed, retake_floor_mps) x t``, t the
  scan time since that sighting, speed the person's recent one (a standing person may walk
  off), for ``retake_max_s``. It is not centred where the target should be by its velocity:
  people walking round a robot turn while unseen (demo_stationary, docs/tracker_log.md
  "Issue 35"). A track in it may be taken unless it was tracked already ``retake_young_s``
  before that sighting: that is someone else (a passer-by crossing the gap keeps the track it
  had), while a track started just before it may be the person's own, split off as the
  target's track lost them (demo_stationary). It must also have been confirmed, have taken
  a candidate this scan and lie at least ``laser_reacquire_min_range_m`` from the laser
  (nearer is the robot's own body); walking or standing. Of several, the one nearest to
  where the target should be now: the sighting moved on at its velocity. With vision alive
  the laser re-takes too: a track vision rejected since the loss is not taken, and a loss
  vision caused (its rejections, stale input) is not re-taken by the laser at all; vision's
  later verifications confirm the re-take or drop it (``reject_votes``).
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from followbot.services.common.geometry import Pose
from followbot.services.common.geometry import rotation as _rot

from .lifecycle import ScanTime, Track, Tracks
from .search import Search
from .settings import TrackerSettings

__all__ = ["RETAKES", "NearLoss", "Reach", "Sighting"]

_NS = 1_000_000_000


class Sighting(msgspec.Struct):
    """The target's last sighting, kept in the odometry frame (the base frame without odometry)."""

    xy: tuple[float, float]
    v: tuple[float, float]  # its recent velocity, same frame
    seen_ns: int
    odometry: bool  # xy and v are in the odometry frame


def sighting_of(track: Track, tracks: Tracks, pose: Pose | None) -> Sighting:
    """Where and when ``track`` was last updated, and how fast it walked."""
    v = tracks.velocity(track, None)  # the odometry frame: the steps' own
    if track.anchor is not None:  # its position after the last update (lifecycle.py)
        xy, odometry = track.anchor, pose is not None
    else:  # no coasting memory: the estimate, in the base frame
        xy, odometry = (float(track.position[0]), float(track.position[1])), False
        if pose is not None:
            v = _rot(-pose[2]) @ v
    return Sighting(
        (float(xy[0]), float(xy[1])), (float(v[0]), float(v[1])), track.last_seen_ns, odometry
    )


def _to_base(xy: np.ndarray, sighting: Sighting, pose: Pose | None) -> np.ndarray:
    if not sighting.odometry or pose is None:
        return xy
    return _rot(-pose[2]) @ (xy - np.array(pose[:2]))


class NearLoss:
    """``near_loss``: today's rule (module doc); it reads the loss from search.py."""

    def __init__(self, settings: TrackerSettings, tracks: Tracks, search: Search, now: ScanTime):
        self.settings, self._tracks, self._search, self._now = settings, tracks, search, now

    def lost(self, track: Track) -> None:
        """The laser lost the target (search.py has noted where)."""

    def forget(self) -> None:
        """The target was lost otherwise (vision, stale input) or taken again."""

    def pick(
        self, z: np.ndarray, matched: dict[int, int], vision: bool, coasting: Track | None
    ) -> int:
        """The track to re-take, or -1. ``coasting``: the target's track while it coasts past
        the miss budget (this rule never takes over from it)."""
        si = self.settings.identity
        lost_at = self._search.lost_at
        if coasting is not None or vision or lost_at is None or si.laser_reacquire_m <= 0:
            return -1
        max_s = si.laser_reacquire_max_s
        if max_s is not None and self._now.stamp_ns - self._search.lost_ns > max_s * _NS:
            return -1  # lost too long ago: whoever passes there now is someone else
        best, best_d = -1, si.laser_reacquire_m
        for tid, ci in matched.items():
            d = float(np.hypot(*(z[ci] - lost_at)))
            if (
                d <= best_d
                and float(np.hypot(*z[ci])) >= si.laser_reacquire_min_range_m
                and self._tracks.walking(tid, si.laser_reacquire_min_speed_mps)
            ):
                best, best_d = tid, d
        return best


class Reach:
    """``reach``: the gate of where the person could have walked (module doc)."""

    def __init__(self, settings: TrackerSettings, tracks: Tracks, search: Search, now: ScanTime):
        self.settings, self._tracks, self._search, self._now = settings, tracks, search, now
        self._sighting: Sighting | None = None  # of a target the laser lost

    def lost(self, track: Track) -> None:
        self._sighting = sighting_of(track, self._tracks, self._now.pose)

    def forget(self) -> None:
        self._sighting = None

    def gate(self, sighting: Sighting) -> tuple[np.ndarray, float, np.ndarray] | None:
        """(centre: the last sighting, radius, where the target should be now) in the base
        frame, or None once retake_max_s has passed since the sighting."""
        si = self.settings.identity
        t = (self._now.stamp_ns - sighting.seen_ns) / _NS
        if t > si.retake_max_s:
            return None
        pose = self._now.pose
        xy, v = np.array(sighting.xy), np.array(sighting.v)
        speed = max(float(np.hypot(*v)), si.retake_floor_mps)
        centre = _to_base(xy, sighting, pose)
        return centre, si.retake_gate_m + speed * t, _to_base(xy + v * t, sighting, pose)

    def pick(
        self, z: np.ndarray, matched: dict[int, int], vision: bool, coasting: Track | None
    ) -> int:
        sighting = self._sighting
        if coasting is not None:
            sighting = sighting_of(coasting, self._tracks, self._now.pose)
        if sighting is None:
            return -1
        g = self.gate(sighting)
        if g is None:
            return -1
        centre, radius, ahead = g
        s = self.settings
        old = sighting.seen_ns - round(s.identity.retake_young_s * _NS)
        best, best_d = -1, math.inf
        for tid, ci in matched.items():
            t = self._tracks.by_id.get(tid)
            if (
                t is None
                or t is coasting
                or t.born_ns < old  # tracked long before the sighting: someone else
                or t.hits < s.confirm_hits
                or self._search.rejected(tid)
                or float(np.hypot(*z[ci])) < s.identity.laser_reacquire_min_range_m
                or float(np.hypot(*(z[ci] - centre))) > radius
            ):
                continue
            d = float(np.hypot(*(z[ci] - ahead)))
            if d < best_d:
                best, best_d = tid, d
        return best


#: identity.laser_retake name -> its rule
RETAKES = {"near_loss": NearLoss, "reach": Reach}
