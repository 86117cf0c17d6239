"""The wire message of one scan's candidates, and a person built from its legs."""

from __future__ import annotations

import math

from followbot.schemas import Candidate, LaserScan, Leg, PersonCandidates

from .clusters import LegSet

#: Most candidates one message may carry (schemas: MAX_ITEMS).
MAX_CANDIDATES = 256


def empty_candidates(scan: LaserScan, detector: str) -> PersonCandidates:
    return candidates_message(scan, detector, [])


def candidates_message(
    scan: LaserScan, detector: str, candidates: list[Candidate]
) -> PersonCandidates:
    """The wire message for one scan: same stamp, frame and seq as the scan; closest first
    when more than the schema's bound must be dropped."""
    if len(candidates) > MAX_CANDIDATES:
        candidates = sorted(candidates, key=lambda c: c.range_m)[:MAX_CANDIDATES]
    return PersonCandidates(
        stamp_ns=scan.stamp_ns,
        frame_id=scan.frame_id,
        seq=scan.seq,
        detector=detector,
        n_beams=int(scan.ranges.shape[0]),
        candidates=candidates,
    )


def person(
    legs: list[Leg], pattern: str, confidence: float, x_m: float | None = None, y_m=None
) -> Candidate:
    """A person at the midpoint of its legs (thesis 4.3.3), unless given a position.

    Width: a lone leg's width, or the legs' separation plus half of each leg's width.
    """
    if len(legs) == 2:
        a, b = legs
        if x_m is None or y_m is None:
            x_m = (a.x_m + b.x_m) / 2
            y_m = (a.y_m + b.y_m) / 2
        width = math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) + 0.5 * (a.width_m + b.width_m)
    else:
        if x_m is None or y_m is None:
            x_m = sum(leg.x_m for leg in legs) / len(legs)
            y_m = sum(leg.y_m for leg in legs) / len(legs)
        width = legs[0].width_m if legs else 0.0
    return Candidate(
        x_m=x_m,
        y_m=y_m,
        range_m=math.hypot(x_m, y_m),
        bearing_rad=math.atan2(y_m, x_m),
        width_m=width,
        legs=legs,
        pattern=pattern,
        confidence=confidence,
    )


def leg_list(legs: LegSet) -> list[Leg]:
    """The legs as wire structs (x, y, beam span, width)."""
    return [
        Leg(x_m=x, y_m=y, first_beam=f, last_beam=la, width_m=w)
        for x, y, f, la, w in zip(
            legs.x.tolist(),
            legs.y.tolist(),
            legs.first.tolist(),
            legs.last.tolist(),
            legs.width_m.tolist(),
            strict=True,
        )
    ]
