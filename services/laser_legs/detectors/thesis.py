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
8. Beyond the thesis (``occluded_partner``): a lone leg whose neighbouring run of beams lies
   just behind it — starting where the leg's edge hides it, ending in a jump to something
   farther (or no return), narrower than a leg, within ``pair_distance_m`` — has its other leg
   half hidden behind it. That sliver fails criterion 2 (too narrow), so the thesis reports a
   one-leg person at the visible leg, 0.1-0.2 m off the person's centre. The two make a
   two-leg person; the sliver's leg is placed half the visible leg's width behind the sliver,
   along its bearing, and given the visible leg's width. Only for a leg with no other leg
   within ``pair_distance_m``: where people cross, the sliver may be someone else's. In the
   simulator (thesis eval, ristic_circles) 198 of the 200 one-leg scans of the tracked target
   were such a hidden leg. Off by default (docs/laser_legs.md, "Half-hidden legs").
"""

from __future__ import annotations

import functools
import math
from typing import Literal

import msgspec
import numpy as np

from followbot.schemas import LaserScan, Leg, PersonCandidates

from ..core import (
    NO_RETURN,
    Anchor,
    LegSet,
    Prediction,
    beam_geometry,
    bridged,
    candidates_message,
    empty_candidates,
    gate,
    gate_xy,
    paired_candidates,
    person,
)

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


class ThesisSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`ClusterLegDetector`; defaults are the thesis values."""

    clip_range_m: float | None = 3.5  # thesis 4.3.1: ranges > 3.5 m set to 3.5 m
    cluster_jump_m: float = 0.060  # thesis 4.3.1: 60 mm
    cluster_bridge_m: float | None = 0.12
    """Beyond the thesis (default since the thirteenth session): a jump shorter than this is
    a cut only when it holds one beam farther on both sides, so range noise does not cut a
    leg in two (core.jump_cuts; must exceed cluster_jump_m). Table 5.1 undetected 1.3 ->
    0.2 %; 76 closed-loop runs: RMSE <= 0.08 m on 67 (54), re-acquisition 1.68 -> 0.81 s on
    average, but 6.7 s on wrong people (4.1) and 3 two-person runs with a switch (2)
    (docs/laser_legs.md, "Noise inside a leg"). None: the thesis's cut at every jump of 60
    mm or more."""
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
    ``pair_first`` (default since the tenth session, beyond the thesis): pair every leg of the
    scan first and keep the persons whose centre lies within gate_m, so a passer-by's leg
    inside the gate pairs with its partner outside it, not with one of the target's
    (docs/laser_legs.md, "Criterion 3 after the pairing")."""
    pair_distance_m: float = 0.500  # thesis 4.3.3: legs closer than 500 mm are one person
    pairing: Literal["closest_first", "matching"] = "matching"
    """thesis 4.3.3 pairs the closest legs first; ``matching`` (default since the tenth
    session, with pair_first) keeps two people walking side by side or crossing apart
    (core.pair_legs)."""
    anchor_weight: float = 1.0
    """Beyond the thesis (default since the eleventh session), with ``pairing: matching`` and
    ``outside_gate: pair_first``: among the groupings of the scan's legs with as many pairs as
    the matching's, prefer the one with a person near the tracked target's prediction --
    metres of pair weight (``pair_distance_m - d``) per metre nearer (core.Anchor,
    core.pair_legs). Where a passer-by walks just in front of the target, the matching alone
    pairs the two people's near legs (docs/laser_legs.md, "Pairing near the target"). 0: off
    (the tenth session's pairing)."""
    anchor_lone_leg_m: float = 0.15
    """A lone leg's distance to the prediction counts this much less (a person's centre lies
    ~0.13 m from a leg seen alone in the simulator)."""
    lone_leg_offset_m: float = 0.0
    """Beyond the thesis, off by default: a one-leg person with no other leg of the scan
    within ``lone_leg_clear_m`` is placed this far beyond its leg, along the bearing. A leg
    seen alone is mostly the near one hiding the other, half a stride behind it. The tracker
    has the same option (tracking ``lone_leg_offset_m``), but criterion 3 hides the other
    people's legs from it; here every leg of the scan is known. 0: at the leg (the thesis)."""
    lone_leg_clear_m: float = 1.0
    """... only with no other leg of the scan this near: near someone, a leg seen alone may be
    hidden by, or belong with, them."""
    leg_centre_factor: float = math.pi / 8
    """Beyond the thesis: the cluster's middle (4.3.3) lies on the leg's visible surface, not
    at its centre. Beams evenly spread in angle hit a round leg of radius R evenly across its
    width as seen from the laser, so their points average pi R / 4 in front of the centre; with
    the end-to-end width W ~ 2R the leg is moved this factor times W further along its bearing
    (default pi/8). 0 gives the thesis's literal position (~0.8 R, 5 cm, short)."""
    two_leg_confidence: float = 1.0  # not in the thesis: two legs are the surer pattern
    one_leg_confidence: float = 0.5  # not in the thesis
    occluded_partner: bool = False
    """Beyond the thesis (module docstring, step 8): pair a lone leg with the sliver of the leg
    it half hides. Off by default: it lowers the target's RMSE in most scenarios but lost the
    target more often in closed loop (docs/laser_legs.md, "Half-hidden legs")."""
    min_partner_beams: int = 2
    """The fewest beams a hidden leg's sliver must show (one beam is as likely an edge)."""
    edge_slivers: bool = False
    """Beyond the thesis (twelfth session, off by default): a leg half hidden behind
    something that is no leg (a pillar, a box) shows as a sliver too few beams or too narrow
    for eq. 4-4 and criterion 2. A run of at least ``min_edge_beams`` beams, narrower than
    ``min_width_m`` or too few, that starts where a nearer run (not a leg) ends and ends in a
    jump to something farther (or no return) is taken as such a leg: its centre is placed
    ``edge_leg_radius_m`` behind the sliver, towards the occluder's side by what the sliver
    does not show. In occlusion_pillar the target's legs came out beside the pillar as such
    slivers for 0.4-0.6 s before a whole leg showed (docs/laser_legs.md)."""
    min_edge_beams: int = 3
    """edge_slivers: a sliver of fewer beams than this is not taken as a half-hidden leg."""
    edge_occluder_min_width_m: float = 0.0
    """... only behind something at least this wide end to end (0: anything that is no leg;
    e.g. 0.3, criterion 2's upper bound: no one leg, so in a crowd a person's legs do not
    count as occluders)."""
    edge_only_searching: bool = False
    """... only in scans without a prediction (criterion 3 off: no target tracked, or it is
    hidden or lost), where a person coming out from behind something is to be found; while
    the target is tracked, a sliver beside it is as likely a passer-by's leg."""
    edge_pairs: bool = True
    """... False: a sliver's leg is a one-leg person of its own (pattern ``edge_leg``), never
    paired: beside a passer-by, two such legs (one of each person) make a cross pair."""
    edge_alone_m: float = 0.0
    """... only with no whole leg this near (0: anywhere; e.g. 0.5, pair_distance_m: a sliver
    beside a person may be their other leg or a passer-by's)."""
    edge_leg_radius_m: float = 0.06
    """Radius of the leg a sliver belongs to (a leg is ~0.12 m across)."""

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
        if not (self.lone_leg_offset_m >= 0 and self.lone_leg_clear_m >= 0):
            raise ValueError("lone_leg_offset_m and lone_leg_clear_m must be >= 0")
        if not (self.anchor_weight >= 0 and self.anchor_lone_leg_m >= 0):
            raise ValueError("anchor_weight and anchor_lone_leg_m must be >= 0")
        if not self.pair_distance_m >= 0:
            raise ValueError("pair_distance_m must be >= 0")
        if self.min_partner_beams < 1:
            raise ValueError("min_partner_beams must be >= 1")
        if self.min_edge_beams < 2 or not self.edge_leg_radius_m > 0:
            raise ValueError("need min_edge_beams >= 2 and edge_leg_radius_m > 0")
        if not (self.edge_occluder_min_width_m >= 0 and self.edge_alone_m >= 0):
            raise ValueError("edge_occluder_min_width_m and edge_alone_m must be >= 0")


class ClusterLegDetector:
    """Clusters + criteria 1-3 + 500 mm pairing (thesis 3.4, 4.3)."""

    name = "thesis"
    settings_type = ThesisSettings

    def __init__(self, settings: ThesisSettings | None = None) -> None:
        self.settings = settings or ThesisSettings()
        self._ref_arc = self.settings.ref_increment_rad * self.settings.ref_range_m

    def legs(self, scan: LaserScan, prediction: Prediction = None) -> LegSet:
        """The accepted legs (criteria 1-3) of one scan, before pairing."""
        wire = self._legs(scan, False)[0]
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

    def _legs(
        self, scan: LaserScan, partners: bool, edges_ok: bool = True
    ) -> tuple[list[Leg], list[Leg | None], list[Leg]]:
        """The legs passing criteria 1-2 of one scan, before criterion 3 (the caller's) and
        pairing, and (``partners``) for each the sliver of a leg it half hides (step 8), or
        None.

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
        # have r = NO_RETURN < 0 and fail the count test below.
        d = np.subtract(rpp[1:], rpp[:-1])
        np.abs(d, out=d)
        cut = (d >= s.cluster_jump_m).nonzero()[0]
        if s.cluster_bridge_m is not None:  # noise steps inside a leg are not cuts
            cut = bridged(rpp, d, cut, s.cluster_jump_m, s.cluster_bridge_m)
        if cut.shape[0] < 2:
            return [], [], []
        rp = rpp[1:]  # n + 1 long, so the last cut (<= n) is a valid index
        cuts = cut.tolist()
        firsts = rp[cut].tolist()  # firsts[i]: range at run i's first beam
        lasts = rpp[cut].tolist()  # lasts[i + 1]: range at run i's last beam
        chord = _chord_list(inc, n)
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
        found = []  # (run, count, width) passing the count and width tests
        narrow = []  # edge_slivers: (run, count, width) of valid runs too few or too narrow
        edge_c = s.min_edge_beams if s.edge_slivers and edges_ok else n + 1
        runs = zip(cuts, cuts[1:], firsts, lasts[1:], strict=False)  # cuts, firsts: one more
        for i, (a, b, ra, rb) in enumerate(runs):
            c = b - a
            if c < 3 and c < edge_c:
                continue
            rm2 = ra + rb  # twice the mean end range
            if not (lo_c < c * rm2 < hi_c if scaled else lo_c < c < hi_c and ra > 0.0):
                # (unscaled: and a run of valid beams); edge_slivers: too few beams
                if c >= edge_c and ra > 0.0 and (c * rm2 if scaled else c) <= lo_c:
                    narrow.append((i, c, _end_width(ra, rb, chord[c])))
                continue
            if c < 3:
                continue
            w = _end_width(ra, rb, chord[c])  # criterion 2
            w_eq = w + rm2 * half_shift if half_shift else w
            if w_lo < w_eq < w_hi:
                found.append((i, c, w))
            elif c >= edge_c and w_eq <= w_lo:
                narrow.append((i, c, w))
        if not found and not narrow:
            return [], [], []
        # criterion 1, eq. 3-8: the closest point is not an end point (both ends farther)
        mins = np.minimum.reduceat(rp, cut).tolist()
        kept = [f for f in found if firsts[f[0]] > mins[f[0]] < lasts[f[0] + 1]]
        edges = self._edge_slivers(narrow, kept, cuts, firsts, lasts, chord) if narrow else []
        if not kept and not edges:
            return [], [], []
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
        if edges:
            extra = self._edge_legs(edges, cuts, sums, cssn, rpp_raw)
            if s.edge_alone_m > 0:  # not beside someone's leg: in a crowd it may be theirs
                keep = [
                    all(math.hypot(g.x_m - k.x_m, g.y_m - k.y_m) >= s.edge_alone_m for k in wire)
                    for g in extra
                ]
                extra = [g for g, k in zip(extra, keep, strict=True) if k]
                edges = [e for e, k in zip(edges, keep, strict=True) if k]
            wire.extend(extra)
            wire.sort(key=lambda g: g.first_beam)
            kept = sorted(kept + [(i, c, w) for i, c, w, _ in edges])  # in step with wire
        else:
            extra = []
        hidden: list[Leg | None] = []
        if partners:
            hidden = self._hidden_partners(kept, cuts, firsts, lasts, chord, sums)
        return wire, hidden, extra

    def _edge_slivers(
        self, narrow, kept, cuts, firsts, lasts, chord
    ) -> list[tuple[int, int, float, int]]:
        """edge_slivers: the narrow runs ``(run, count, width, side)`` that start where a
        nearer run wider than ``edge_occluder_min_width_m`` ends (side -1: it is the run
        before, +1: after) and end in a jump to something farther or to no return."""
        legs = {i for i, _, _ in kept}
        n_runs = len(firsts) - 1
        wide = self.settings.edge_occluder_min_width_m

        def occluder(j: int) -> bool:  # run j is no leg and wider than a person's leg
            c = cuts[j + 1] - cuts[j]
            return j not in legs and _end_width(firsts[j], lasts[j + 1], chord[c]) >= wide

        out = []
        for i, c, w in narrow:
            first, last = firsts[i], lasts[i + 1]
            # the runs either side: their range at the sliver (-1: none, or no return)
            before = lasts[i] if i > 0 else -1.0
            after = firsts[i + 1] if i + 1 < n_runs else -1.0
            if 0 < before < first and (after < 0 or after > last) and occluder(i - 1):
                out.append((i, c, w, -1))
            elif 0 < after < last and (before < 0 or before > first) and occluder(i + 1):
                out.append((i, c, w, 1))
        return out

    def _edge_legs(self, edges, cuts, sums, cssn, rpp_raw) -> list[Leg]:
        """The legs behind ``edges`` (from :meth:`_edge_slivers`): the sliver's centroid moved
        one leg radius back along its bearing, and sideways towards the occluder by the part
        of the leg's width the sliver does not show."""
        rad = self.settings.edge_leg_radius_m
        out = []
        for i, c, w, side in edges:
            cx, cy = (sums[:, i] / c).tolist()
            r = max(math.hypot(cx, cy), 1e-9)
            end = cuts[i] if side < 0 else cuts[i + 1] - 1  # the beam beside the occluder
            ex, ey = (cssn[:, end] * rpp_raw[end + 1]).tolist()
            dx, dy = ex - cx, ey - cy
            d = math.hypot(dx, dy)
            lateral = max(rad - 0.5 * w, 0.0) / d if d > 1e-9 else 0.0
            x = cx * (1 + rad / r) + dx * lateral
            y = cy * (1 + rad / r) + dy * lateral
            out.append(
                Leg(x_m=x, y_m=y, first_beam=cuts[i], last_beam=cuts[i + 1] - 1, width_m=2 * rad)
            )
        return out

    def _hidden_partners(self, kept, cuts, firsts, lasts, chord, sums) -> list[Leg | None]:
        """Step 8: for each kept run ``(i, count, width)``, the sliver of a leg it half hides,
        or None.

        Runs are contiguous in beam order, so a leg's neighbours are runs ``j = i -+ 1``.
        A neighbour is a hidden leg's sliver when it is no leg itself, starts behind the leg's
        edge (farther, within ``pair_distance_m``), shows at least ``min_partner_beams`` beams,
        is narrower than ``max_width_m``, and its far side jumps to something farther (or to no
        return): a wall or a larger object behind the leg continues past it instead.
        """
        s = self.settings
        n_runs = len(cuts) - 1
        legs = {i for i, _, _ in kept}
        out: list[Leg | None] = []
        for i, c_i, w_i in kept:
            best, best_d = None, math.inf
            for j, far in ((i + 1, i + 2), (i - 1, i - 2)):  # the run right, or left, of it
                if not 0 <= j < n_runs or j in legs:
                    continue
                c_j = cuts[j + 1] - cuts[j]
                if c_j < s.min_partner_beams:
                    continue
                right = j > i
                near_edge = lasts[i + 1] if right else firsts[i]  # the leg's range at its edge
                # the sliver's range at the leg's edge and at its far end
                start, end = (firsts[j], lasts[j + 1]) if right else (lasts[j + 1], firsts[j])
                if not (near_edge < start <= near_edge + s.pair_distance_m):
                    continue
                # the next run's range beyond the sliver (-1: none, as no return)
                beyond = -1.0
                if 0 <= far < n_runs:
                    beyond = firsts[far] if right else lasts[far + 1]
                if 0 < beyond <= end:  # something nearer (or as near) continues past it
                    continue
                if not _end_width(firsts[j], lasts[j + 1], chord[c_j]) < s.max_width_m:
                    continue
                cx, cy = (sums[:, j] / c_j).tolist()
                lx, ly = (sums[:, i] / c_i).tolist()
                d = math.hypot(cx - lx, cy - ly)
                if d < s.pair_distance_m and d < best_d:
                    r = math.hypot(cx, cy)
                    push = 0.5 * w_i / max(r, 1e-9)  # half a leg behind the sliver
                    best, best_d = (cx * (1 + push), cy * (1 + push), j), d
            if best is None:
                out.append(None)
            else:
                bx, by, j = best
                # its width: the visible leg's (only a sliver of it shows)
                out.append(
                    Leg(x_m=bx, y_m=by, first_beam=cuts[j], last_beam=cuts[j + 1] - 1, width_m=w_i)
                )
        return out

    def _alone(self, wire: list[Leg], i: int) -> bool:
        """No other leg within ``pair_distance_m`` of leg ``i``: where people cross, a sliver
        behind a leg may as well be another person's, so step 8 keeps out of crowds."""
        a = wire[i]
        d = self.settings.pair_distance_m
        return all(
            j == i or math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) >= d for j, b in enumerate(wire)
        )

    def detect(self, scan: LaserScan, prediction: Prediction = None) -> PersonCandidates:
        s = self.settings
        searching = prediction is None or not s.edge_only_searching
        legs, hidden, edge = self._legs(scan, s.occluded_partner, searching)
        # edge_pairs off: the slivers' legs (by identity) stand alone
        lone = frozenset(map(id, edge)) if edge and not s.edge_pairs else frozenset()
        if prediction is None:
            return self._offset(self._paired(scan, legs, hidden, lone=lone), legs)
        if s.outside_gate == "pair_first":  # criterion 3 on the persons' centres
            anchor = None
            px, py = float(prediction[0]), float(prediction[1])
            if s.anchor_weight and math.isfinite(px) and math.isfinite(py):
                anchor = Anchor(px, py, s.anchor_weight, s.gate_m, s.anchor_lone_leg_m)
            people = self._paired(scan, legs, hidden, anchor, lone)
            people = self._offset(people, legs).candidates
            near = gate_xy([c.x_m for c in people], [c.y_m for c in people], prediction, s.gate_m)
            kept = [c for c, ok in zip(people, near.tolist(), strict=True) if ok]
            return candidates_message(scan, self.name, kept)
        # criterion 3, eq. 4-7: near the tracker's prediction (keep_apart: the rest apart)
        near = gate_xy([g.x_m for g in legs], [g.y_m for g in legs], prediction, s.gate_m)
        parts = [self._offset(self._part(scan, legs, hidden, near.tolist(), lone), legs)]
        if s.outside_gate == "keep_apart":
            rest = self._part(scan, legs, hidden, (~near).tolist(), lone)
            parts.append(self._offset(rest, legs))
            return candidates_message(scan, self.name, [c for m in parts for c in m.candidates])
        return parts[0]

    def _offset(self, found: PersonCandidates, legs: list[Leg]) -> PersonCandidates:
        """``lone_leg_offset_m``: each one-leg person with no other of ``legs`` within
        ``lone_leg_clear_m`` moved that far beyond its leg, along the bearing."""
        s = self.settings
        if not s.lone_leg_offset_m:
            return found
        moved = False
        out = []
        for c in found.candidates:
            if len(c.legs) == 1 and c.range_m > 0:
                g = c.legs[0]
                if all(
                    o is g or math.hypot(o.x_m - g.x_m, o.y_m - g.y_m) >= s.lone_leg_clear_m
                    for o in legs
                ):
                    k = 1.0 + s.lone_leg_offset_m / c.range_m
                    c = person(c.legs, c.pattern, c.confidence, c.x_m * k, c.y_m * k)
                    moved = True
            out.append(c)
        return msgspec.structs.replace(found, candidates=out) if moved else found

    def _part(
        self,
        scan: LaserScan,
        legs: list[Leg],
        hidden: list[Leg | None],
        keep: list[bool],
        lone: frozenset[int],
    ):
        """The persons among the legs ``keep`` selects, paired among themselves."""
        mine = [h for h, ok in zip(hidden, keep, strict=True) if ok] if hidden else []
        chosen = [g for g, ok in zip(legs, keep, strict=True) if ok]
        return self._paired(scan, chosen, mine, lone=lone)

    def _paired(
        self,
        scan: LaserScan,
        legs: list[Leg],
        hidden: list[Leg | None],
        anchor: Anchor | None = None,
        lone: frozenset[int] = frozenset(),
    ):
        """The persons of ``legs``; those whose id is in ``lone`` (edge_pairs off) each a
        one-leg person of its own, never paired."""
        s = self.settings
        alone = []
        if lone:
            alone = [person([g], "edge_leg", s.one_leg_confidence) for g in legs if id(g) in lone]
            keep = [id(g) not in lone for g in legs]
            hidden = [h for h, k in zip(hidden, keep, strict=True) if k] if hidden else []
            legs = [g for g, k in zip(legs, keep, strict=True) if k]
        found = self._paired_whole(scan, legs, hidden, anchor) if legs else None
        if not alone:
            return found or empty_candidates(scan, self.name)
        return candidates_message(scan, self.name, [*(found.candidates if found else ()), *alone])

    def _paired_whole(self, scan, legs, hidden, anchor):
        s = self.settings

        def partner(wire: list[Leg], i: int) -> Leg | None:  # step 8
            return hidden[i] if hidden[i] is not None and self._alone(wire, i) else None

        return paired_candidates(
            scan,
            self.name,
            legs,
            s.pair_distance_m,
            s.two_leg_confidence,
            s.one_leg_confidence,
            partner if any(h is not None for h in hidden) else None,
            s.pairing,
            anchor,
        )
