"""The thesis's leg detector (thesis 3.4, 4.3; DESIGN.md "Leg candidates") — the default.

1. Ranges beyond 3.5 m are set to 3.5 m (4.3.1).
2. Consecutive beams share a cluster while ``|r_k - r_{k-1}| < 60 mm`` (3.4.1 eq. 3-6, 4.3.1).
3. Point-count bounds, eq. 4-4: ``5 < n < 40`` at 0.5 deg and about 1.5 m. A cluster of ``n``
   beams at range ``r`` with increment ``dtheta`` spans an arc of about ``n * r * dtheta``, so
   the bounds are kept as that arc: ``n_min(r) = 5 * (0.5 deg * 1.5 m) / (dtheta * r)`` and the
   same for 40. At 0.5 deg and 1.5 m this is the thesis's 5 < n < 40; at other resolutions and
   ranges it keeps the same physical meaning (Table 4.3: beams on a leg fall as 1/range).
   ``scale_count_with_range=False`` scales with resolution only (fixed range 1.5 m). At least
   3 beams are always needed (criterion 1 needs an interior point).
4. Criterion 1 (eq. 3-8): the closest point is not an end point — strictly: both end points
   are farther than the cluster's minimum (a cluster whose end ties the minimum, e.g. a run
   clipped flat at 3.5 m, is not convex toward the robot).
5. Criterion 2 (eq. 4-5, 4-6): ``W = sqrt(r_a^2 + r_b^2 - 2 r_a r_b cos(theta_b - theta_a))``,
   ``80 mm < W < 300 mm``. The end beams lie inside an object's outline, so W falls short of
   its true width by about one beam spacing ``r * dtheta``; the bounds are the thesis's at
   0.5 deg, and at other resolutions W is compared after adding ``r * (dtheta - 0.5 deg)``
   (identical at 0.5 deg; a 1 deg scanner would otherwise lose most legs beyond 1.5 m).
6. Criterion 3 (eq. 4-7, tracking stage only): the leg lies within 400 mm of the prediction.
   The digest states it as a distance to the predicted position (used here); eq. 4-7 as
   printed compares ranges only.
7. A leg is at the middle (centroid) of its cluster; legs closer than 500 mm pair into one
   person at their midpoint, closest pairs first; a lone leg is a one-leg person (4.3.3).
"""

from __future__ import annotations

import math

import msgspec

from followbot.schemas import LaserScan, PersonCandidates

from ..core import (
    LegSet,
    Prediction,
    cluster_by_jump,
    cluster_min,
    empty_candidates,
    end_width,
    gate,
    paired_candidates,
    prepare,
)

__all__ = ["ClusterLegDetector", "ThesisSettings"]


class ThesisSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`ClusterLegDetector`; defaults are the thesis values."""

    clip_range_m: float | None = 3.5  # thesis 4.3.1: ranges > 3.5 m set to 3.5 m
    cluster_jump_m: float = 0.060  # thesis 4.3.1: 60 mm
    min_points_ref: float = 5.0  # thesis 4.3.1 eq. 4-4: 5 < points
    max_points_ref: float = 40.0  # thesis 4.3.1 eq. 4-4: points < 40
    ref_increment_rad: float = math.radians(0.5)  # thesis 4.1: 0.5 deg scanner
    ref_range_m: float = 1.5  # thesis 4.3.1: person about 1.5 m away
    scale_count_with_range: bool = True
    min_width_m: float = 0.080  # thesis 4.3.2 eq. 4-5: 80 mm < W
    max_width_m: float = 0.300  # thesis 4.3.2 eq. 4-5: W < 300 mm
    gate_m: float = 0.400  # thesis 4.3.2 eq. 4-7: 400 mm (criterion 3)
    pair_distance_m: float = 0.500  # thesis 4.3.3: legs closer than 500 mm are one person
    two_leg_confidence: float = 1.0  # not in the thesis: two legs are the surer pattern
    one_leg_confidence: float = 0.5  # not in the thesis

    def __post_init__(self) -> None:
        if self.clip_range_m is not None and not self.clip_range_m > 0:
            raise ValueError("clip_range_m must be > 0 or None")
        if not 0 < self.min_width_m < self.max_width_m:
            raise ValueError("need 0 < min_width_m < max_width_m")
        if not 0 < self.min_points_ref < self.max_points_ref:
            raise ValueError("need 0 < min_points_ref < max_points_ref")
        for name in ("cluster_jump_m", "ref_increment_rad", "ref_range_m", "gate_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if not self.pair_distance_m >= 0:
            raise ValueError("pair_distance_m must be >= 0")


class ClusterLegDetector:
    """Clusters + criteria 1-3 + 500 mm pairing (thesis 3.4, 4.3)."""

    name = "thesis"
    settings_type = ThesisSettings

    def __init__(self, settings: ThesisSettings | None = None) -> None:
        self.settings = settings or ThesisSettings()
        self._ref_arc = self.settings.ref_increment_rad * self.settings.ref_range_m

    def legs(self, scan: LaserScan, prediction: Prediction = None) -> LegSet:
        """The accepted legs (criteria 1-3) of one scan, before pairing."""
        s = self.settings
        b = prepare(scan, s.clip_range_m)
        c = cluster_by_jump(b, s.cluster_jump_m)
        if len(c) == 0:
            return LegSet.empty()
        starts, ends = c.starts, c.ends
        gaps = ends - starts  # n - 1
        ra, rb = b.r[starts], b.r[ends]
        # eq. 4-4 scaled to the scanner and range: n beams at range r span n * r * dtheta;
        # the thesis's 5 < n < 40 at 0.5 deg and 1.5 m becomes a bound on that arc
        lo, hi = s.min_points_ref * self._ref_arc, s.max_points_ref * self._ref_arc
        r_mid = 0.5 * (ra + rb)
        if s.scale_count_with_range:
            arc = (gaps + 1) * r_mid * b.increment_rad
        else:
            arc = (gaps + 1) * (b.increment_rad * s.ref_range_m)
        keep = (arc > lo) & (arc < hi) & (gaps >= 2)
        # criterion 2, eq. 4-6: W = sqrt(ra^2 + rb^2 - 2 ra rb cos(tb - ta)), eq. 4-5
        w = end_width(b, c)
        # the end beams fall inside the leg's outline, so W falls short of the leg's width by
        # about one beam spacing r * dtheta; the thesis's bounds hold at 0.5 deg, so shift W
        # by the difference in spacing to keep their meaning at other resolutions
        w_eq = w + r_mid * (b.increment_rad - s.ref_increment_rad)
        keep &= (w_eq > s.min_width_m) & (w_eq < s.max_width_m)
        # criterion 1, eq. 3-8: the closest point is not an end point (both ends farther)
        m = cluster_min(b.rp, c)
        keep &= (ra > m) & (rb > m)
        legs = LegSet.from_clusters(b, c.select(keep), w[keep])
        # criterion 3, eq. 4-7: near the tracker's prediction
        if prediction is not None:
            legs = legs.select(gate(legs, prediction, s.gate_m))
        return legs

    def detect(self, scan: LaserScan, prediction: Prediction = None) -> PersonCandidates:
        legs = self.legs(scan, prediction)
        if len(legs) == 0:
            return empty_candidates(scan, self.name)
        s = self.settings
        return paired_candidates(
            scan,
            self.name,
            legs,
            s.pair_distance_m,
            s.two_leg_confidence,
            s.one_leg_confidence,
        )
