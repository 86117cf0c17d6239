"""Track lifecycle: start, confirmation (the initiator), misses and deletion, coasting.

A track starts on every candidate no track took, and is a person -- reported -- once the
initiator says so (initiators.py: ``hits``, the thesis, after ``confirm_hits`` candidates;
``evidence``, once it travelled as a walker does). It counts one miss per scan without a
candidate and is deleted after more than ``max_misses`` consecutive misses (thesis 3.6.2.8: 8,
about 1 s at 120 ms) or when its estimator says so (the UKF's variance rule).

Coasting: a track that missed moves on at its person's recent velocity -- the median of the
velocities between its last updates over ``coast_velocity_s`` -- instead of staying where it
was last seen. Only for estimators whose own prediction has no velocity memory
(``coasts_in_place``, the thesis's particle filter, whose velocities are redrawn around zero
every step): there a hidden walker was left behind, and a robot following at walking speed
saw the left-behind track drift towards itself and onto a passer-by.
"""

from __future__ import annotations

import math
import statistics
from collections import deque

import msgspec
import numpy as np

from followbot.schemas import Candidate, PersonCandidates
from followbot.services.common.geometry import Pose
from followbot.services.common.geometry import rotation as _rot

from .estimators import Estimator, EstimatorFactory
from .initiators import INITIATORS, Sighting
from .settings import TrackerSettings

__all__ = ["ScanTime", "Track", "Tracks"]

_NS = 1_000_000_000
_I2 = np.eye(2)


class ScanTime(msgspec.Struct):
    """The scan being stepped: its stamp and the robot's odometry pose then (None: unknown).
    One instance is shared by the tracker's roles."""

    stamp_ns: int = 0
    pose: Pose | None = None


class Track:
    """One tracked person: an estimator plus the bookkeeping of the tracker."""

    __slots__ = (
        "anchor",
        "born_ns",
        "estimator",
        "evidence",
        "hits",
        "id",
        "last_seen_ns",
        "misses",
        "person",
        "shift",
        "steps",
    )

    def __init__(self, track_id: int, estimator: Estimator, stamp_ns: int) -> None:
        self.id = track_id
        self.estimator = estimator
        self.misses = 0
        self.hits = 1
        self.born_ns = stamp_ns
        self.last_seen_ns = stamp_ns
        self.anchor: tuple[float, float] | None = None
        """Position after the last update, in the odometry frame (for coasting)."""
        self.steps: deque[tuple[int, float, float]] = deque()
        """(stamp, vx, vy): velocity between two updates, odometry frame, recent updates."""
        self.shift = np.zeros(2)
        """Added to the estimate in what the tracker reports (lone_leg_output_m), base frame."""
        self.person = False
        """The initiator confirmed it (initiators.py): reported, and stays so until deleted."""
        self.evidence: object | None = None
        """What the initiator gathered towards confirming it."""

    @property
    def reported(self) -> np.ndarray:
        """(2,) the position the tracker reports: the estimate plus its lone-leg shift."""
        return self.estimator.mean[:2] + self.shift

    @property
    def position(self) -> np.ndarray:
        return self.estimator.mean[:2]


class Tracks:
    """Every track by id: starts, counts, coasts and deletes them."""

    def __init__(self, settings: TrackerSettings, make: EstimatorFactory, now: ScanTime) -> None:
        self.settings = settings
        self._make = make
        self._now = now
        self.by_id: dict[int, Track] = {}
        self._next_id = 1
        self.initiator = INITIATORS[settings.initiator](settings)

    def new(
        self,
        xy: np.ndarray,
        stamp_ns: int,
        candidate: Candidate | None = None,
        message: PersonCandidates | None = None,
    ) -> Track:
        """A track started at ``xy`` (base frame) on ``candidate`` of ``message``; its random
        draws seeded by (seed, id)."""
        tid = self._take_id()
        rng = np.random.default_rng([self.settings.seed, tid])
        track = Track(tid, self._make(float(xy[0]), float(xy[1]), rng), stamp_ns)
        self.by_id[tid] = track
        self._took(track, stamp_ns, candidate, message)
        if self.settings.coast_velocity_s > 0:
            self.learn_velocity(track, stamp_ns, self._now.pose)  # where it was first seen
        return track

    def split_off(self, track: Track, hits: int) -> Track:
        """A new track that takes over ``track``'s estimator (a rollback: ``track`` followed
        someone else, who keeps the estimate under a new id)."""
        other = Track(self._take_id(), track.estimator, track.born_ns)
        other.hits, other.misses = hits, track.misses
        other.person = True  # the one the target followed: a person
        other.last_seen_ns = track.last_seen_ns
        self.by_id[other.id] = other
        return other

    def _take_id(self) -> int:
        tid = self._next_id
        self._next_id += 1
        return tid

    def predict(
        self, rotation: np.ndarray | None, translation: np.ndarray | None, dt: float
    ) -> None:
        """Ego-motion (when the frame change is known), the estimators' prediction, then
        coasting at the people's recent velocity."""
        tracks = list(self.by_id.values())
        if tracks:
            estimators, misses = [t.estimator for t in tracks], [t.misses for t in tracks]
            self._make.estimator_class.motion_all(estimators, rotation, translation, dt, misses)

    def coast(self, dt: float) -> None:
        """Tracks that missed their candidate last scan move on at their coasting velocity."""
        if self.settings.coast_velocity_s <= 0:
            return
        for t in self.by_id.values():
            if t.misses > 0 and t.steps and t.estimator.coasts_in_place:
                t.estimator.ego_motion(_I2, self.velocity(t, self._now.pose) * dt)

    def count(
        self,
        ids: list[int],
        matched: dict[int, Candidate],
        stamp: int,
        message: PersonCandidates | None = None,
    ) -> list[tuple[Track, int]]:
        """A hit or a miss for each of ``ids`` (``matched``: track id -> the candidate of
        ``message`` it took, its estimate updated with it); returns (track, last seen before
        this scan) of those that took a candidate, whose velocities :meth:`learn_velocity`
        records later."""
        learn: list[tuple[Track, int]] = []
        for tid in ids:
            t = self.by_id[tid]
            if tid in matched:
                if self.settings.coast_velocity_s > 0:
                    learn.append((t, t.last_seen_ns))
                t.misses = 0
                t.hits += 1
                t.last_seen_ns = stamp
                self._took(t, stamp, matched[tid], message)
            else:
                t.misses += 1
        return learn

    def _took(
        self,
        t: Track,
        stamp: int,
        candidate: Candidate | None,
        message: PersonCandidates | None,
    ) -> None:
        """Tell the initiator that ``t`` took ``candidate`` of ``message``: where its estimate
        is after the update, in the odometry frame when the scan's pose is known."""
        xy = np.array(t.estimator.mean[:2], dtype=float)
        pose = self._now.pose
        if pose is not None:
            xy = _rot(pose[2]) @ xy + np.array(pose[:2])
        self.initiator.took(t, Sighting(xy, pose is not None, stamp, candidate, message))

    def delete_lost(self) -> list[Track]:
        """Delete the tracks past ``max_misses`` or expired by their estimator; returns them."""
        gone = [
            t
            for t in self.by_id.values()
            if t.misses > self.settings.max_misses or t.estimator.expired()
        ]
        for t in gone:
            del self.by_id[t.id]
        return gone

    def learn_velocity(
        self, t: Track, stamp: int, pose: Pose | None, seen_ns: int | None = None
    ) -> None:
        """Record the track's step velocity (odometry frame: nothing to turn with the robot);
        ``seen_ns``: when it was seen before this update (default: ``t.last_seen_ns``)."""
        m = t.estimator.mean
        x, y = float(m[0]), float(m[1])
        if pose is not None:
            c, sn = math.cos(pose[2]), math.sin(pose[2])
            x, y = pose[0] + c * x - sn * y, pose[1] + sn * x + c * y
        seen = t.last_seen_ns if seen_ns is None else seen_ns
        if t.anchor is not None and stamp > seen:
            gap = (stamp - seen) / _NS
            t.steps.append((stamp, (x - t.anchor[0]) / gap, (y - t.anchor[1]) / gap))
            oldest = stamp - self.settings.coast_velocity_s * _NS
            while t.steps[0][0] < oldest:
                t.steps.popleft()
        t.anchor = (x, y)

    def velocity(self, t: Track, pose: Pose | None) -> np.ndarray:
        """The median of the track's recent step velocities, in the robot frame of ``pose``,
        clipped to ``coast_max_speed_mps``; (0, 0) before two updates."""
        if not t.steps:
            return np.zeros(2)
        # statistics.median: the same value as numpy's for these few samples, ~20x cheaper
        v = np.array(
            [
                statistics.median([st[1] for st in t.steps]),
                statistics.median([st[2] for st in t.steps]),
            ]
        )
        if pose is not None:
            v = _rot(-pose[2]) @ v
        speed = float(np.hypot(*v))
        cap = self.settings.coast_max_speed_mps
        return v * (cap / speed) if speed > cap else v

    def walking(self, tid: int, min_speed_mps: float) -> bool:
        """Track ``tid`` moves at ``min_speed_mps`` or faster (recent velocity); any track
        when ``min_speed_mps`` is 0."""
        if min_speed_mps <= 0:
            return True
        t = self.by_id.get(tid)
        if t is None:
            return False
        return float(np.hypot(*self.velocity(t, self._now.pose))) >= min_speed_mps

    def nearest(self, xy: np.ndarray, within_m: float) -> int:
        """The id of the track nearest ``xy`` within ``within_m``, or -1."""
        best, best_d = -1, within_m
        for tid, t in self.by_id.items():
            d = float(np.hypot(*(t.position - xy)))
            if d <= best_d:
                best, best_d = tid, d
        return best
