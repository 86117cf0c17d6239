"""First-derivative-of-depth segmentation (seed 004, Ristic-Durrant et al., 4.2 and 5.1).

* depth ``l_i`` per beam and its first derivative ``d_i = l_i - l_{i-1}`` (eq. 14), zeroed where
  ``|d_i| < t`` (eq. 15 ff.);
* ``d_i < 0`` (the beam comes closer) marks a potential object start, ``d_i > 0`` an end: the
  object ``L_Aa`` runs from start ``A`` to the beam before the next positive jump (eq. 16-17);
* a segment belongs to the laser ROI when its end-to-end distance ``D_Aa <= D_T`` (eq. 18):
  the limited width of the ankle-calf area;
* persons: one or two such segments (legs together or apart). Without a prediction, segments
  whose centres lie within the search window's half size pair up; with a prediction, only
  segments inside the 1 m x 1 m search window centred on it count (5.1).

Seed 004 measures depth along the scanner's forward axis (``X = r sin(theta)`` with its
bearing from the lateral axis). That depth degenerates for beams at +-90 deg, so ``depth="x"``
reproduces the seed and ``depth="range"`` (default) uses the range, which works for any field
of view. Seed 004 gives no values for ``t`` and ``D_T``; the defaults below are choices.
"""

from __future__ import annotations

import math
from typing import Literal

import msgspec
import numpy as np

from followbot.schemas import LaserScan, PersonCandidates

from ..beams import Beams, prepare
from ..clusters import Clusters, LegSet, end_width
from ..core import LaserPose, Prediction
from ..message import candidates_message, leg_list, person
from ..pairing import pair_legs

__all__ = ["DerivativeSegmentDetector", "DerivativeSettings"]

#: Depth given to beams without return: farther than anything real.
_FAR = 1.0e6


class DerivativeSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    depth: Literal["range", "x"] = "range"  # seed 004 eq. 10-11 uses "x"; see module doc
    threshold_m: float = 0.10  # seed 004 eq. 15 "t": no value given
    max_width_m: float = 0.30  # seed 004 eq. 18 "D_T": no value; thesis 4.3.2 leg <= 300 mm
    min_width_m: float = 0.05  # not in seed 004: drop single-beam slivers
    min_points: int = 3  # not in seed 004
    window_m: float = 1.0  # seed 004 5.1: search window 1 m x 1 m
    two_leg_confidence: float = 0.8
    """PersonCandidate.confidence of a person of two segments (reported; the tracker does
    not weigh by it)."""
    one_leg_confidence: float = 0.4
    """PersonCandidate.confidence of a person of one segment."""

    def __post_init__(self) -> None:
        if not self.threshold_m > 0:
            raise ValueError("threshold_m must be > 0")
        if not 0 <= self.min_width_m < self.max_width_m:
            raise ValueError("need 0 <= min_width_m < max_width_m")
        if self.min_points < 1:
            raise ValueError("min_points must be >= 1")


class DerivativeSegmentDetector:
    """Segments between a negative and the next positive depth jump, narrower than D_T."""

    name = "derivative"
    settings_type = DerivativeSettings

    def __init__(self, settings: DerivativeSettings | None = None) -> None:
        self.settings = settings or DerivativeSettings()

    def segments(self, scan: LaserScan) -> tuple[Clusters, np.ndarray, Beams]:
        s = self.settings
        b = prepare(scan)
        # depth per beam, padded at both ends; a beam without return reads as far away, so a
        # step into a hole ends an object and a step out of one may start an object
        depth = b.r * b.cos if s.depth == "x" else b.r
        lp = np.full(b.n + 2, _FAR)
        np.copyto(lp[1:-1], depth, where=b.valid)
        # eq. 14: d_k = l_k - l_{k-1}; index k of d is beam k (k = 0..n, pads included)
        d = np.diff(lp)
        neg = np.flatnonzero(d <= -s.threshold_m)  # starts: beam k comes closer
        pos = np.flatnonzero(d >= s.threshold_m)  # ends: beam k goes farther -> end k - 1
        if neg.shape[0] == 0 or pos.shape[0] == 0:
            return Clusters(neg[:0], neg[:0]), np.zeros(0), b
        # pair each end with the latest start before it (innermost object, eq. 17)
        j = np.searchsorted(neg, pos, side="left") - 1
        ok = j >= 0
        starts, ends = neg[j[ok]], pos[ok] - 1
        # one segment per start: the first end after it
        first = np.ones(starts.shape[0], dtype=bool)
        first[1:] = starts[1:] != starts[:-1]
        starts, ends = starts[first], ends[first]
        good = (ends >= starts) & b.valid[starts] & (ends - starts + 1 >= s.min_points)
        c = Clusters(starts[good], ends[good])
        # every beam of a segment must have a return
        if len(c):
            holes = np.concatenate(([0], np.cumsum(~b.valid)))
            c = c.select(holes[c.ends + 1] - holes[c.starts] == 0)
        w = end_width(b, c)
        keep = (w >= s.min_width_m) & (w <= s.max_width_m)  # eq. 18: D_Aa <= D_T
        return c.select(keep), w[keep], b

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        s = self.settings
        c, w, b = self.segments(scan)
        if len(c) == 0:
            return candidates_message(scan, self.name, [])
        legs = LegSet.from_clusters(b, c, w)
        if prediction is not None and all(map(math.isfinite, prediction)):
            # seed 004 5.1: only segments inside the search window around the prediction
            half = s.window_m / 2
            px, py = float(prediction[0]), float(prediction[1])
            legs = legs.select((np.abs(legs.x - px) <= half) & (np.abs(legs.y - py) <= half))
        wire = leg_list(legs)
        groups = pair_legs([g.x_m for g in wire], [g.y_m for g in wire], s.window_m / 2)
        people = [
            person([wire[i] for i in g], "two_legs", s.two_leg_confidence)
            if len(g) == 2
            else person([wire[g[0]]], "one_leg", s.one_leg_confidence)
            for g in groups
        ]
        return candidates_message(scan, self.name, people)
