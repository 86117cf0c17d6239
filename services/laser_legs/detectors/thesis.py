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
   printed compares ranges only. By default (``outside_gate: pair_first``, beyond the thesis)
   it is applied after step 7 to the persons' centres, so that a passer-by's leg inside the
   gate pairs with its own partner outside it; ``drop`` applies it to the legs, as printed.
7. A leg is at the middle (centroid) of its cluster, computed from the measured ranges (the
   criteria see the clipped ones); legs closer than 500 mm pair into one person at their
   midpoint -- the thesis pairs the closest first (``pairing: closest_first``); by default the
   best matching (``matching``, beyond the thesis); a lone leg is a one-leg person (4.3.3).
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, Literal

import msgspec
import numpy as np

from followbot.schemas import LaserScan, Leg, PersonCandidates
from followbot.services.common.scan import beam_geometry
from followbot.services.runtime.settings import removed

from ..beams import NO_RETURN
from ..clusters import LegSet, bridged, gate, gate_xy
from ..core import LaserPose, Prediction
from ..message import candidates_message, empty_candidates
from ..pairing import Anchor, paired_candidates

__all__ = ["ClusterLegDetector", "ThesisSettings"]

_HALF_DEG = math.radians(0.5)


@functools.lru_cache(maxsize=32)
def _cos_sin(angle_min_rad: float, increment_rad: float, n: int) -> np.ndarray:
    """(2, n + 1) cosines and sines of every beam, padded with a 0 (``core.beam_geometry``)."""
    _, cos, sin = beam_geometry(angle_min_rad, increment_rad, n)
    cs = np.stack([cos, sin])
    cs.flags.writeable = False
    return cs


@functools.lru_cache(maxsize=32)
def _chord_list(increment_rad: float, n: int) -> tuple[float, ...]:
    """``4 sin^2((c - 1) dtheta / 2)`` for a run of ``c`` beams (index c = 0..n+1): the squared
    chord of unit radius between a run's end beams."""
    c = np.arange(n + 2, dtype=np.float64)
    t = 2.0 * np.sin(0.5 * np.maximum(c - 1.0, 0.0) * increment_rad)
    t *= t
    return tuple(t.tolist())


def _end_width(ra: float, rb: float, chord: float) -> float:
    """Criterion 2, eq. 4-6: ``W^2 = ra^2 + rb^2 - 2 ra rb cos(dtheta_ab)``, computed as
    ``(ra - rb)^2 + ra rb 4 sin^2(dtheta_ab / 2)`` with ``chord`` from :func:`_chord_list`."""
    dr = ra - rb
    return math.sqrt(dr * dr + ra * rb * chord)


_LOG = "docs/laser_legs.md and docs/tracker_log.md"

#: Detector settings that are gone: experiments measured and left off.
RETIRED_SETTINGS: dict[str, str] = {
    "occluded_partner": removed(
        f"pairing a lone leg with a half-hidden sliver, measured in {_LOG}"
    ),
    "min_partner_beams": removed("it only applied with occluded_partner, also removed"),
    "edge_slivers": removed(f"legs half hidden behind an occluder, measured in {_LOG}"),
    "min_edge_beams": removed("it only applied with edge_slivers, also removed"),
    "edge_occluder_min_width_m": removed("it only applied with edge_slivers, also removed"),
    "edge_only_searching": removed("it only applied with edge_slivers, also removed"),
    "edge_pairs": removed("it only applied with edge_slivers, also removed"),
    "edge_alone_m": removed("it only applied with edge_slivers, also removed"),
    "edge_leg_radius_m": removed("it only applied with edge_slivers, also removed"),
    "lone_leg_offset_m": removed(
        f"moving a lone leg's person beyond it, measured in {_LOG}; the tracker's "
        "lone_leg_output_m moves the report"
    ),
    "lone_leg_clear_m": removed("it only applied with lone_leg_offset_m, also removed"),
}


class ThesisSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`ClusterLegDetector`; defaults are the thesis values unless marked
    beyond the thesis (those chosen by the closed-loop runs of docs/laser_legs.md)."""

    retired_settings: ClassVar[dict[str, str]] = RETIRED_SETTINGS

    clip_range_m: float | None = 3.5  # thesis 4.3.1: ranges > 3.5 m set to 3.5 m
    cluster_jump_m: float = 0.060  # thesis 4.3.1: 60 mm
    cluster_bridge_m: float | None = 0.12
    """Beyond the thesis: a jump shorter than this is a cut only when it holds one beam
    farther on both sides, so range noise does not cut a leg in two (core.jump_cuts; must
    exceed cluster_jump_m; docs/laser_legs.md, "Noise inside a leg"). None: the thesis's cut
    at every jump of 60 mm or more."""
    min_points_ref: float = 5.0  # thesis 4.3.1 eq. 4-4: 5 < points
    max_points_ref: float = 40.0  # thesis 4.3.1 eq. 4-4: points < 40
    ref_increment_rad: float = math.radians(0.5)  # thesis 4.1: 0.5 deg scanner
    ref_range_m: float = 1.5  # thesis 4.3.1: person about 1.5 m away
    scale_count_with_range: bool = True
    """Eq. 4-4's point bounds scale with each cluster's range (the beams on a leg fall as
    1/range, thesis Table 4.3); False: with the scanner's resolution only, at ref_range_m."""
    min_width_m: float = 0.080  # thesis 4.3.2 eq. 4-5: 80 mm < W
    max_width_m: float = 0.300  # thesis 4.3.2 eq. 4-5: W < 300 mm
    gate_m: float = 0.400  # thesis 4.3.2 eq. 4-7: 400 mm (criterion 3)
    outside_gate: Literal["drop", "keep_apart", "pair_first"] = "pair_first"
    """Criterion 3's legs farther than gate_m from the target's prediction: ``drop`` them
    before the pairing (the thesis: it follows one person), ``keep_apart`` -- report them
    too, paired only among themselves, so the target's legs still never pair with anyone
    else's while everybody else's tracks keep being fed (tracking/people) -- or
    ``pair_first`` (beyond the thesis): pair every leg of the scan first and keep the persons
    whose centre lies within gate_m, so a passer-by's leg inside the gate pairs with its
    partner outside it, not with one of the target's (docs/laser_legs.md, "Criterion 3 after
    the pairing")."""
    pair_distance_m: float = 0.500  # thesis 4.3.3: legs closer than 500 mm are one person
    pairing: Literal["closest_first", "matching"] = "matching"
    """thesis 4.3.3 pairs the closest legs first; ``matching`` (beyond the thesis, with
    pair_first) keeps two people walking side by side or crossing apart (pairing.pair_legs)."""
    anchor_weight: float = 1.0
    """Beyond the thesis, with ``pairing: matching`` and ``outside_gate: pair_first``: among
    the groupings of the scan's legs with as many pairs as the matching's, prefer the one with
    a person near the tracked target's prediction -- metres of pair weight (``pair_distance_m
    - d``) per metre nearer (pairing.Anchor, pairing.pair_legs). Where a passer-by walks just in
    front of the target, the matching alone pairs the two people's near legs
    (docs/laser_legs.md, "Pairing near the target"). 0: off."""
    anchor_lone_leg_m: float = 0.15
    """A lone leg's distance to the prediction counts this much less (a person's centre lies
    ~0.13 m from a leg seen alone in the simulator)."""
    leg_centre_factor: float = math.pi / 8
    """Beyond the thesis: the cluster's middle (4.3.3) lies on the leg's visible surface, not
    at its centre. Beams evenly spread in angle hit a round leg of radius R evenly across its
    width as seen from the laser, so their points average pi R / 4 in front of the centre; with
    the end-to-end width W ~ 2R the leg is moved this factor times W further along its bearing
    (default pi/8). 0 gives the thesis's literal position (~0.8 R, 5 cm, short)."""
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
        if self.cluster_bridge_m is not None and not self.cluster_bridge_m > self.cluster_jump_m:
            raise ValueError("cluster_bridge_m must be above cluster_jump_m (or null: off)")
        if not 0 <= self.leg_centre_factor <= 1:
            raise ValueError("leg_centre_factor must be in [0, 1]")
        if not (self.anchor_weight >= 0 and self.anchor_lone_leg_m >= 0):
            raise ValueError("anchor_weight and anchor_lone_leg_m must be >= 0")
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
        wire = self._legs(scan)
        if not wire:
            return LegSet.empty()
        legs = LegSet(
            np.array([g.x_m for g in wire]),
            np.array([g.y_m for g in wire]),
            np.array([g.first_beam for g in wire], dtype=np.intp),
            np.array([g.last_beam for g in wire], dtype=np.intp),
            np.array([g.width_m for g in wire]),
        )
        if prediction is None:
            return legs
        return legs.select(gate(legs, prediction, self.settings.gate_m))  # criterion 3

    def _legs(self, scan: LaserScan) -> list[Leg]:
        """The legs passing criteria 1-2 of one scan, before criterion 3 (the caller's) and
        pairing.

        Few numpy calls: each costs ~1-2 us whatever the array size, which dominates at 720
        beams. numpy does the full-scan work (validity, clipping, the jump cuts, and one
        ``reduceat`` each for the runs' minima and sums); the per-run tests are plain Python
        on a scan's few dozen runs, where a float operation costs ~0.03 us.
        ``tests/laser_legs/test_fast_paths.py`` checks it against the step-by-step version
        built from ``core`` helpers.
        """
        s = self.settings
        raw = scan.ranges_m()
        n = raw.shape[0]
        inc_signed = float(scan.angle_increment_rad)
        inc = abs(inc_signed) or _HALF_DEG
        # "no return" beams (NaN, inf, 0, out of bounds) -> NO_RETURN; ranges clipped (4.3.1)
        lo = float(scan.range_min_m)
        valid = raw >= lo if lo > 0 else raw > 0.0
        valid &= raw <= scan.range_max_m
        rpp_raw = np.empty(n + 2)
        rpp_raw.fill(NO_RETURN)  # not np.full: a Python-level wrapper, ~1 us more
        np.copyto(rpp_raw[1:-1], raw, where=valid)
        # the criteria see clipped ranges; leg positions use the measured ones (a leg seen at
        # 3.52 m is placed there, not on the 3.5 m clip circle)
        rpp = rpp_raw if s.clip_range_m is None else np.minimum(rpp_raw, s.clip_range_m)
        # eq. 3-6: a run of beams with |r_k - r_k-1| < 60 mm (no-return beams always cut).
        # Runs are contiguous: run i is beams cut[i] .. cut[i + 1] - 1; runs of no-return beams
        # have r = NO_RETURN < 0 and fail the count test.
        d = np.subtract(rpp[1:], rpp[:-1])
        np.abs(d, out=d)
        cut = (d >= s.cluster_jump_m).nonzero()[0]
        if s.cluster_bridge_m is not None:  # noise steps inside a leg are not cuts
            cut = bridged(rpp, d, cut, s.cluster_jump_m, s.cluster_bridge_m)
        if cut.shape[0] < 2:
            return []
        rp = rpp[1:]  # n + 1 long, so the last cut (<= n) is a valid index
        cuts = cut.tolist()
        firsts = rp[cut].tolist()  # firsts[i]: range at run i's first beam
        lasts = rpp[cut].tolist()  # lasts[i + 1]: range at run i's last beam
        found = self._sized(cuts, firsts, lasts, inc, _chord_list(inc, n))
        if not found:
            return []
        # criterion 1, eq. 3-8: the closest point is not an end point (both ends farther)
        mins = np.minimum.reduceat(rp, cut).tolist()
        kept = [f for f in found if firsts[f[0]] > mins[f[0]] < lasts[f[0] + 1]]
        if not kept:
            return []
        # a leg is the centroid ("middle", 4.3.3) of its cluster
        cssn = _cos_sin(float(scan.angle_min_rad), inc_signed, n)
        sums = np.add.reduceat(cssn * rpp_raw[1:], cut, axis=1)
        sx, sy = sums[:, [i for i, _, _ in kept]].tolist()
        factor = s.leg_centre_factor
        wire = []
        for (i, c, w), x, y in zip(kept, sx, sy, strict=True):
            x /= c
            y /= c
            if factor:  # from the visible surface to the leg's centre, along the bearing
                push = 1 + factor * w / max(math.hypot(x, y), 1e-9)
                x, y = x * push, y * push
            wire.append(Leg(x_m=x, y_m=y, first_beam=cuts[i], last_beam=cuts[i + 1] - 1, width_m=w))
        return wire

    def _sized(
        self,
        cuts: list[int],
        firsts: list[float],
        lasts: list[float],
        inc: float,
        chord: tuple[float, ...],
    ) -> list[tuple[int, int, float]]:
        """The runs ``(run, beam count, end-to-end width)`` passing eq. 4-4's point bounds and
        criterion 2's width bounds, both scaled to the scanner (module docstring, 3 and 5)."""
        s = self.settings
        # eq. 4-4 scaled to the scanner and range: n beams at range r span n * r * dtheta;
        # at least 3 beams (criterion 1 needs an interior point)
        lo_arc, hi_arc = s.min_points_ref * self._ref_arc, s.max_points_ref * self._ref_arc
        scaled = s.scale_count_with_range
        if scaled:  # compared as 2 * arc / dtheta = count * (ra + rb)
            lo_c, hi_c = 2.0 * lo_arc / inc, 2.0 * hi_arc / inc
        else:
            lo_c, hi_c = lo_arc / (s.ref_range_m * inc), hi_arc / (s.ref_range_m * inc)
        # the end beams fall inside the leg's outline, so W falls short of the leg's width by
        # about one beam spacing r * dtheta; the thesis's bounds hold at 0.5 deg, so shift W
        # by the difference in spacing to keep their meaning at other resolutions
        shift = inc - s.ref_increment_rad
        half_shift = 0.5 * shift if abs(shift) > 1e-12 else 0.0
        w_lo, w_hi = s.min_width_m, s.max_width_m
        found = []
        runs = zip(cuts, cuts[1:], firsts, lasts[1:], strict=False)  # cuts, firsts: one more
        for i, (a, b, ra, rb) in enumerate(runs):
            c = b - a
            if c < 3:
                continue
            rm2 = ra + rb  # twice the mean end range
            # (unscaled: and a run of valid beams)
            if not (lo_c < c * rm2 < hi_c if scaled else lo_c < c < hi_c and ra > 0.0):
                continue
            w = _end_width(ra, rb, chord[c])  # criterion 2
            w_eq = w + rm2 * half_shift if half_shift else w
            if w_lo < w_eq < w_hi:
                found.append((i, c, w))
        return found

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        s = self.settings
        legs = self._legs(scan)
        if prediction is None:
            return self._paired(scan, legs)
        if s.outside_gate == "pair_first":  # criterion 3 on the persons' centres
            anchor = None
            px, py = float(prediction[0]), float(prediction[1])
            if s.anchor_weight and math.isfinite(px) and math.isfinite(py):
                anchor = Anchor(px, py, s.anchor_weight, s.gate_m, s.anchor_lone_leg_m)
            people = self._paired(scan, legs, anchor).candidates
            near = gate_xy([c.x_m for c in people], [c.y_m for c in people], prediction, s.gate_m)
            kept = [c for c, ok in zip(people, near.tolist(), strict=True) if ok]
            return candidates_message(scan, self.name, kept)
        # criterion 3, eq. 4-7: near the tracker's prediction (keep_apart: the rest apart)
        near = gate_xy([g.x_m for g in legs], [g.y_m for g in legs], prediction, s.gate_m)
        inside = self._paired(scan, [g for g, ok in zip(legs, near.tolist(), strict=True) if ok])
        if s.outside_gate == "keep_apart":
            rest = [g for g, ok in zip(legs, near.tolist(), strict=True) if not ok]
            out = [*inside.candidates, *self._paired(scan, rest).candidates]
            return candidates_message(scan, self.name, out)
        return inside

    def _paired(
        self, scan: LaserScan, legs: list[Leg], anchor: Anchor | None = None
    ) -> PersonCandidates:
        """The persons of ``legs`` (thesis 4.3.3, ``pairing``)."""
        if not legs:
            return empty_candidates(scan, self.name)
        s = self.settings
        return paired_candidates(
            scan,
            self.name,
            legs,
            s.pair_distance_m,
            s.two_leg_confidence,
            s.one_leg_confidence,
            None,
            s.pairing,
            anchor,
        )
