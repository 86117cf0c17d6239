"""Inscribed-angle arc test — the leg detector the thesis compares against (thesis 3.4.2, 5.2.1).

The thesis's reference [29] finds a leg as a circular arc: every interior point P of a cluster
sees its end points A and B under the same inscribed angle APB (eq. 3-7), about 90 deg for the
half circle a leg shows the laser. The thesis reports this test as "low false alarm but high
undetected probability" (Table 5.1: 48.8 % one leg, 31.8 % two legs, 19.4 % undetected).

The acceptance band is the inscribed-angle-variance test of Xavier et al. (ICRA 2005, cited as
[6] by seed 003): mean inscribed angle within [90, 135] deg and standard deviation below
8.6 deg. Those two numbers are from that paper, not from the seeds. Clustering and pairing are
the thesis's (60 mm jump, 500 mm pairing), so only the leg test differs from ``thesis``; the
leg width band is the thesis's "usual diameter of a human leg, 0.1 m to 0.25 m" (3.4.2).
"""

from __future__ import annotations

import math

import msgspec

from followbot.schemas import LaserScan, PersonCandidates

from ..beams import prepare
from ..clusters import LegSet, cluster_by_jump, end_width, gate, inscribed_angle_stats
from ..core import LaserPose, Prediction
from ..message import empty_candidates
from ..pairing import paired_candidates

__all__ = ["ArcSettings", "InscribedAngleArcDetector"]


class ArcSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`InscribedAngleArcDetector`."""

    clip_range_m: float | None = 3.5  # thesis 4.3.1 (same pre-processing as `thesis`)
    cluster_jump_m: float = 0.060  # thesis 4.3.1: 60 mm
    min_points: int = 4  # at least two interior points for a variance
    min_mean_angle_rad: float = math.radians(90.0)  # Xavier 2005: mean in [90, 135] deg
    max_mean_angle_rad: float = math.radians(135.0)  # Xavier 2005
    max_std_angle_rad: float = math.radians(8.6)  # Xavier 2005: std < 8.6 deg
    min_width_m: float = 0.10  # thesis 3.4.2: leg diameter 0.1 m ..
    max_width_m: float = 0.25  # thesis 3.4.2: .. 0.25 m
    gate_m: float = 0.400  # thesis 4.3.2 eq. 4-7 (criterion 3, when a prediction is given)
    pair_distance_m: float = 0.500  # thesis 4.3.3
    two_leg_confidence: float = 1.0
    """PersonCandidate.confidence of a person of two legs (reported; the tracker does not
    weigh by it)."""
    one_leg_confidence: float = 0.6
    """PersonCandidate.confidence of a person seen as one leg."""

    def __post_init__(self) -> None:
        if self.min_points < 3:
            raise ValueError("min_points must be >= 3 (an inscribed angle needs 3 points)")
        if not 0 <= self.min_mean_angle_rad < self.max_mean_angle_rad <= math.pi:
            raise ValueError("need 0 <= min_mean_angle_rad < max_mean_angle_rad <= pi")
        if not 0 <= self.min_width_m < self.max_width_m:
            raise ValueError("need 0 <= min_width_m < max_width_m")
        if not self.cluster_jump_m > 0:
            raise ValueError("cluster_jump_m must be > 0")


class InscribedAngleArcDetector:
    """Legs are clusters whose inscribed angles are nearly constant around 90-135 deg."""

    name = "arc"
    settings_type = ArcSettings

    def __init__(self, settings: ArcSettings | None = None) -> None:
        self.settings = settings or ArcSettings()

    def legs(self, scan: LaserScan, prediction: Prediction = None) -> LegSet:
        s = self.settings
        b = prepare(scan, s.clip_range_m)
        c = cluster_by_jump(b, s.cluster_jump_m)
        c = c.select(c.counts >= s.min_points)
        w = end_width(b, c)
        keep = (w >= s.min_width_m) & (w <= s.max_width_m)
        c, w = c.select(keep), w[keep]
        mean, std = inscribed_angle_stats(b, c)
        ok = (mean >= s.min_mean_angle_rad) & (mean <= s.max_mean_angle_rad)
        ok &= std < s.max_std_angle_rad
        legs = LegSet.from_clusters(b, c.select(ok), w[ok])
        if prediction is not None:
            legs = legs.select(gate(legs, prediction, s.gate_m))
        return legs

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        legs = self.legs(scan, prediction)
        if len(legs) == 0:
            return empty_candidates(scan, self.name)
        s = self.settings
        return paired_candidates(
            scan, self.name, legs, s.pair_distance_m, s.two_leg_confidence, s.one_leg_confidence
        )
