"""Initiators: when a tentative track becomes a person (the ``initiator`` setting).

Every candidate no track took starts a tentative track; the initiator decides when that track
is a *person*: reported in tracking/people, looked at by the camera while the target is lost
(search.py), and a possible first target without vision (identity.py). The decision is
latched: a person stays one (standing still included) until its track is deleted. Tentative
tracks associate, coast and are deleted like any other.

- ``hits`` (the thesis): a person once the track took ``confirm_hits`` candidates.
- ``evidence``: a person only on evidence clutter lacks (``evidence.*`` settings): the track
  took enough candidates and travelled -- its estimate moved ``min_travel_m`` away from where
  it was first seen, in the odometry frame (the static world stands still there: a chair or a
  door frame seen by a moving robot does not travel) -- along a consistent path (net
  displacement against path length: a track jittering in place or hopping between clutter is
  not), at a walker's plausible speed, and, optionally, on candidates the detector was
  confident of. A candidate at the edge of the laser's view is no evidence: there the end of
  a wall slides along with the robot as it drives. ROS leg_tracker likewise asks a leg pair
  to travel together ~0.5 m before it is a person. Without odometry the base frame stands for
  the world: right for a still robot; on a moving robot without odometry every static thing
  seems to walk with it, and only a scan-matching odometry can tell them apart.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Protocol

import msgspec
import numpy as np

from followbot.schemas import Candidate, PersonCandidates

from .settings import EvidenceSettings, TrackerSettings

__all__ = [
    "INITIATORS",
    "Evidence",
    "EvidenceInitiator",
    "HitsInitiator",
    "Initiator",
    "Sighting",
    "at_view_edge",
]

_NS = 1_000_000_000


class _Track(Protocol):  # what an initiator reads and writes of lifecycle.Track
    hits: int
    person: bool
    evidence: object | None


class Sighting(msgspec.Struct, frozen=True):
    """A track started on, or updated with, a candidate: where its estimate is after that."""

    xy: np.ndarray
    """(2,) the estimate, odometry frame (``odometry``) or else the base frame."""
    odometry: bool
    stamp_ns: int
    candidate: Candidate | None = None  # None: not from a candidate (a target model)
    message: PersonCandidates | None = None  # the candidate's message


class Initiator(Protocol):
    """Decides when a tentative track is a person; sets ``track.person`` (never resets it)."""

    def took(self, track: _Track, seen: Sighting) -> None: ...


class HitsInitiator:
    """The thesis: a person once the track took ``confirm_hits`` candidates."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.confirm_hits = settings.confirm_hits

    def took(self, track: _Track, seen: Sighting) -> None:
        if track.hits >= self.confirm_hits:
            track.person = True


def at_view_edge(candidate: Candidate, message: PersonCandidates, margin_deg: float) -> bool:
    """A leg of ``candidate`` lies within ``margin_deg`` of either end of the laser's view. A
    full-circle laser has no edge; without legs or a horizon (which gives the view's width)
    nothing tells: False."""
    h, n = message.horizon, message.n_beams
    if margin_deg <= 0 or h is None or not candidate.legs or n < 2:
        return False
    span = h.increment_rad * h.ranges.numpy().shape[0]
    if span >= 2.0 * math.pi - 1e-6:
        return False
    beams = math.radians(margin_deg) / (span / n)  # beams in the margin
    return any(leg.first_beam < beams or n - 1 - leg.last_beam < beams for leg in candidate.legs)


class Evidence:
    """What the ``evidence`` initiator gathered of one track: its recent sightings."""

    __slots__ = ("odometry", "seen")

    def __init__(self, odometry: bool) -> None:
        self.odometry = odometry
        """Positions are in the odometry frame (else the base frame)."""
        self.seen: deque[tuple[int, np.ndarray, float]] = deque()
        """(stamp, position, candidate confidence) of the sightings within evidence.window_s,
        away from the view's edge, oldest first."""


class EvidenceInitiator:
    """A person on travel, path consistency, speed, hits and confidence within a time window
    (module doc)."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.s: EvidenceSettings = settings.evidence

    def took(self, track: _Track, seen: Sighting) -> None:
        c, msg = seen.candidate, seen.message
        if c is not None and msg is not None and at_view_edge(c, msg, self.s.edge_margin_deg):
            return  # no evidence either way
        ev = track.evidence
        if not isinstance(ev, Evidence) or ev.odometry != seen.odometry:
            # new, or odometry came or went: positions in two frames do not compare
            ev = track.evidence = Evidence(seen.odometry)
        confidence = 1.0 if c is None else float(c.confidence)
        ev.seen.append((seen.stamp_ns, np.array(seen.xy, dtype=float), confidence))
        oldest = seen.stamp_ns - self.s.window_s * _NS
        while ev.seen[0][0] < oldest:
            ev.seen.popleft()
        if not track.person and self._convinced(ev):
            track.person = True

    def _convinced(self, ev: Evidence) -> bool:
        s, seen = self.s, ev.seen
        if len(seen) < s.min_hits:
            return False
        (t0, p0, _), (t1, p1, _) = seen[0], seen[-1]
        travel = float(np.hypot(*(p1 - p0)))
        if travel < s.min_travel_m or travel > s.max_speed_mps * (t1 - t0) / _NS:
            return False
        if sum(x[2] for x in seen) < s.min_confidence * len(seen):
            return False
        return travel >= s.min_straightness * self._path(ev)

    def _path(self, ev: Evidence) -> float:
        """The length of the path through the window's positions, between vertices
        path_step_m apart (the estimate's jitter round a standing person adds nothing), to
        the last position."""
        vertex, length = ev.seen[0][1], 0.0
        for _, p, _ in ev.seen:
            step = float(np.hypot(*(p - vertex)))
            if step >= self.s.path_step_m:
                length, vertex = length + step, p
        return length + float(np.hypot(*(ev.seen[-1][1] - vertex)))


#: The initiators by name (the ``initiator`` setting).
INITIATORS: dict[str, Callable[[TrackerSettings], Initiator]] = {
    "hits": HitsInitiator,
    "evidence": EvidenceInitiator,
}
