"""Inscribed angle variance (IAV) features: circles (legs) and narrow segments (leg pairs).

Seed 003 (Livingston) IV and VII: segment the scan by range jumps, compute the mean and
variance of each segment's inscribed angles, and label

* "leg" (pattern ``circle``): a circle-like segment — small inscribed-angle spread, mean within
  the arc band — whose width is a leg's;
* "leg pair" (pattern ``segment``): any other cluster "not necessarily circular, with width
  sufficiently small" that is not a straight line (two legs too close to be split).

Seed 003 gives no numbers ("thresholds determined experimentally, cf. [6]"). The circle band
(mean 90-135 deg, std < 8.6 deg) is that of its reference [6] (Xavier et al. 2005); the line
threshold and the widths are choices made here, documented beside each setting. Legs are not
paired (seed 003 tracks the nearest single leg, else the nearest leg pair).
"""

from __future__ import annotations

import math

import msgspec

from followbot.schemas import LaserScan, PersonCandidates

from ..core import (
    LegSet,
    Prediction,
    candidates_message,
    cluster_by_jump,
    empty_candidates,
    end_width,
    gate,
    inscribed_angle_stats,
    leg_list,
    person,
    prepare,
)

__all__ = ["IAVSettings", "InscribedAngleVarianceDetector"]


class IAVSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    clip_range_m: float | None = None  # seed 003 clips nothing
    cluster_jump_m: float = 0.10  # not in seed 003: 10 cm segmentation jump
    min_points: int = 4
    min_mean_angle_rad: float = math.radians(90.0)  # seed 003 [6] (Xavier 2005)
    max_mean_angle_rad: float = math.radians(135.0)  # seed 003 [6]
    max_std_angle_rad: float = math.radians(8.6)  # seed 003 [6]
    min_leg_width_m: float = 0.10  # thesis 3.4.2: leg diameter 0.1-0.25 m
    max_leg_width_m: float = 0.25
    min_pair_width_m: float = 0.15  # not in seed 003: two legs together
    max_pair_width_m: float = 0.45  # not in seed 003 (Bellotto seed 002: together <= 0.40 m)
    line_mean_angle_rad: float = math.radians(165.0)  # not in seed 003: flatter is a line
    gate_m: float = 0.400  # thesis 4.3.2 (when a prediction is given)
    circle_confidence: float = 0.7
    segment_confidence: float = 0.4

    def __post_init__(self) -> None:
        if self.min_points < 3:
            raise ValueError("min_points must be >= 3")
        if not self.cluster_jump_m > 0:
            raise ValueError("cluster_jump_m must be > 0")


class InscribedAngleVarianceDetector:
    """Circles (single legs) and narrow non-line segments (leg pairs), seed 003."""

    name = "iav"
    settings_type = IAVSettings

    def __init__(self, settings: IAVSettings | None = None) -> None:
        self.settings = settings or IAVSettings()

    def detect(self, scan: LaserScan, prediction: Prediction = None) -> PersonCandidates:
        s = self.settings
        b = prepare(scan, s.clip_range_m)
        c = cluster_by_jump(b, s.cluster_jump_m)
        c = c.select(c.counts >= s.min_points)
        w = end_width(b, c)
        keep = (w >= min(s.min_leg_width_m, s.min_pair_width_m)) & (
            w <= max(s.max_leg_width_m, s.max_pair_width_m)
        )
        c, w = c.select(keep), w[keep]
        if len(c) == 0:
            return empty_candidates(scan, self.name)
        mean, std = inscribed_angle_stats(b, c)
        circle = (mean >= s.min_mean_angle_rad) & (mean <= s.max_mean_angle_rad)
        circle &= (std < s.max_std_angle_rad) & (w >= s.min_leg_width_m)
        circle &= w <= s.max_leg_width_m
        pair = ~circle & (mean < s.line_mean_angle_rad)
        pair &= (w >= s.min_pair_width_m) & (w <= s.max_pair_width_m)
        take = circle | pair
        legs = LegSet.from_clusters(b, c.select(take), w[take])
        is_circle = circle[take]
        if prediction is not None:
            g = gate(legs, prediction, s.gate_m)
            legs, is_circle = legs.select(g), is_circle[g]
        out = [
            person([leg], "circle", s.circle_confidence)
            if circ
            else person([leg], "segment", s.segment_confidence)
            for leg, circ in zip(leg_list(legs), is_circle.tolist(), strict=True)
        ]
        return candidates_message(scan, self.name, out)
