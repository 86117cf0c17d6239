"""Association: which track takes which candidate of a scan.

1. Units: what tracks are associated with. Each candidate is one unit, except a two-leg
   candidate whose legs lie farther apart than ``association.split_pair_m``: it may be one
   leg each of two people. When each leg lies in the gate of a different track (nearest
   first) it becomes two one-leg units; otherwise one unit whose points are its centre and
   each leg, a track taking the point nearest its prediction.
2. Gating: each estimator's distance to each point, infinite beyond its gate; a unit costs
   what its best point costs.
3. Someone in front of the target (``association.front_margin_m``): a unit this much
   nearer to the laser than the target's prediction, on its bearing, that another track's
   gate also holds is not the target's: it is someone passing in front, hiding it.
4. Assignment, one rule by name (``association.assignment``, :data:`ASSIGNMENTS`):
   ``weighted`` -- the assignment of greatest total weight, a gated pair weighing
   (G - distance), G the widest gate of the scan's tracks: a track left unmatched costs G, so a
   second match is made only when it adds less than G to the total distance. One G for all:
   weighing by each track's own gate made coasting tracks, whose gates grow, win candidates
   from nearer tracks (docs/tracker_log.md).
   ``most_matches`` -- as many pairs as the gates allow, and among those the least total
   distance (every gated-out pair priced above any total). That can take a track's best
   candidate away to let another track match at all.
   Both solve with the Hungarian method (``scipy.optimize.linear_sum_assignment``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.optimize import linear_sum_assignment

from followbot.schemas import PersonCandidates
from followbot.services.runtime.mount import LaserMount

from .estimators import EstimatorBase, wrap_angle
from .lifecycle import Track
from .settings import TrackerSettings

__all__ = ["ASSIGNMENTS", "Association", "Associator", "assign_most_matches", "assign_weighted"]

AssignmentRule = Callable[[np.ndarray, float], list[tuple[int, int]]]
"""(cost (tracks, units), infinite where gated out; the widest gate) -> (row, column) pairs."""


def assign_weighted(cost: np.ndarray, widest_gate: float) -> list[tuple[int, int]]:
    """Greatest total (widest_gate - distance) over gated pairs (module doc)."""
    finite = np.isfinite(cost)
    weight = np.where(finite, np.maximum(widest_gate - cost, 0.0), 0.0)
    finite &= weight > 0  # at the gate itself: no better than a miss
    rows, cols = linear_sum_assignment(weight, maximize=True)
    return [(r, c) for r, c in zip(rows.tolist(), cols.tolist(), strict=True) if finite[r, c]]


def assign_most_matches(cost: np.ndarray, widest_gate: float) -> list[tuple[int, int]]:
    """The most gated pairs, and among those the least total distance (module doc)."""
    finite = np.isfinite(cost)
    big = 1e6 + 2.0 * float(cost[finite].max(initial=0.0))
    rows, cols = linear_sum_assignment(np.where(finite, cost, big))
    return [(r, c) for r, c in zip(rows.tolist(), cols.tolist(), strict=True) if finite[r, c]]


#: The assignment rules by name (the ``association.assignment`` setting).
ASSIGNMENTS: dict[str, AssignmentRule] = {
    "weighted": assign_weighted,
    "most_matches": assign_most_matches,
}


class Association:
    """One scan's association: units, their points, and which track took which unit."""

    def __init__(
        self, candidates: PersonCandidates, unit_cand: list[int], points: np.ndarray, starts
    ) -> None:
        self.candidates = candidates
        self.unit_cand = unit_cand
        """Per unit, the index of the candidate it comes from."""
        self.points = points
        """(n, 2) every unit's points, base frame."""
        self.starts: np.ndarray | None = starts
        """Where each unit's points begin in ``points``; None: one point per unit."""
        self.matched: dict[int, int] = {}
        """Track id -> unit index."""
        self.measured: dict[int, np.ndarray] = {}
        """Track id -> the point it is updated with, when not its unit's first point."""

    @property
    def first(self) -> np.ndarray:
        """Per unit, the index of its first point (its centre, or its one leg)."""
        return self.starts if self.starts is not None else np.arange(len(self.unit_cand))

    def point(self, tid: int) -> np.ndarray:
        """The point track ``tid`` is updated with."""
        return self.measured.get(tid, self.points[self.first[self.matched[tid]]])

    def lone_leg(self, tid: int) -> bool:
        """Track ``tid`` is updated with one leg: a one-leg candidate, one leg of a pair, or
        one side of a split pair."""
        c = self.unit_cand[self.matched[tid]]
        return (
            tid in self.measured
            or self.unit_cand.count(c) > 1
            or len(self.candidates.candidates[c].legs) == 1
        )

    def by_candidate(self, target_id: int) -> dict[int, int]:
        """Track id -> the message's candidate index (a split pair: the target's side wins)."""
        by_cand: dict[int, int] = {}
        for tid, u in self.matched.items():
            c = self.unit_cand[u]
            if c not in by_cand or tid == target_id:
                by_cand[c] = tid
        return {tid: c for c, tid in by_cand.items()}


class Associator:
    """Gates, units and the assignment rule, for one estimator class."""

    def __init__(
        self, settings: TrackerSettings, estimator_class: type, mount: LaserMount | None = None
    ) -> None:
        self.settings = settings
        self._cls = estimator_class
        self._mount = mount or LaserMount()  # "in front" is seen from where the laser sits
        self._assign = ASSIGNMENTS[settings.association.assignment]

    def associate(
        self, tracks: dict[int, Track], candidates: PersonCandidates, z: np.ndarray, target_id: int
    ) -> Association:
        """Associate the scan's candidates (``z``: their positions) with ``tracks``."""
        a = Association(candidates, *self._units(tracks, candidates, z))
        ids = list(tracks)
        if not ids or not len(a.unit_cand):
            return a
        cost_p = self._gated(tracks, ids, a.points)
        if a.starts is None:  # one point per unit
            cost, best = cost_p, None
        else:  # a unit's cost is that of its best point (centre or one of its legs)
            cost = np.minimum.reduceat(cost_p, a.starts, axis=1)
            best = np.column_stack(
                [np.argmin(g, axis=1) for g in np.split(cost_p, a.starts[1:], axis=1)]
            )
        if self.settings.association.front_margin_m is not None and target_id in tracks:
            self._block_in_front(cost, ids.index(target_id), tracks[target_id], a)
        if np.isfinite(cost).any():
            widest = max(tracks[tid].estimator.gate(tracks[tid].misses) for tid in ids)
            for r, c in self._assign(cost, widest):
                a.matched[ids[r]] = c
                if best is not None and best[r, c]:
                    a.measured[ids[r]] = a.points[a.starts[c] + best[r, c]]
        return a

    def _gated(self, tracks: dict[int, Track], ids: list[int], points: np.ndarray) -> np.ndarray:
        """(tracks, points) distances, infinite beyond each track's gate."""
        ts = [tracks[tid] for tid in ids]
        # one track: its own distance(), as the batch step of a class may compute it otherwise
        cost_all = self._cls.cost_all if len(ts) > 1 else EstimatorBase.cost_all
        return cost_all([t.estimator for t in ts], points, [t.misses for t in ts])

    def _block_in_front(self, cost: np.ndarray, r: int, target: Track, a: Association) -> None:
        """Someone passing in front of the target hides it: a unit on its bearing, at least
        association.front_margin_m nearer, is not the target's when another track can take it
        (alone, it may be the target coming closer)."""
        s = self.settings
        pred = target.position
        centres = a.points[a.starts] if a.starts is not None else a.points
        if not self._mount.is_identity:
            pred, centres = self._mount.to_laser(pred)[0], self._mount.to_laser(centres)
        r_pred = float(np.hypot(*pred))
        half = math.atan2(s.occlusion_radius_m, max(r_pred, 1e-6))
        dr = r_pred - np.hypot(centres[:, 0], centres[:, 1])
        db = np.abs(wrap_angle(np.arctan2(centres[:, 1], centres[:, 0]) - math.atan2(*pred[::-1])))
        others = np.isfinite(np.delete(cost, r, axis=0)).any(axis=0)
        cost[r, (dr >= s.association.front_margin_m) & (db <= half) & others] = np.inf

    def _units(
        self, tracks: dict[int, Track], candidates: PersonCandidates, z: np.ndarray
    ) -> tuple[list[int], np.ndarray, np.ndarray | None]:
        """(per unit its candidate, every unit's points, where each unit's points begin or
        None when every unit is one point): module doc, step 1."""
        split = self.settings.association.split_pair_m
        cands = candidates.candidates
        wide = set()
        if split:
            wide = {
                c
                for c, cand in enumerate(cands)
                if len(cand.legs) == 2
                and math.hypot(
                    cand.legs[0].x_m - cand.legs[1].x_m, cand.legs[0].y_m - cand.legs[1].y_m
                )
                > split
            }
        if not wide:
            return list(range(len(cands))), z, None
        unit_cand: list[int] = []
        pts: list[np.ndarray] = []
        starts: list[int] = []
        for c, cand in enumerate(cands):
            legs = [np.array([leg.x_m, leg.y_m]) for leg in cand.legs]
            if c in wide and len({_nearest_gated(tracks, leg) for leg in legs} - {-1}) == 2:
                for leg in legs:
                    unit_cand.append(c)
                    starts.append(len(pts))
                    pts.append(leg)
                continue
            unit_cand.append(c)
            starts.append(len(pts))
            pts.append(z[c])
            if c in wide:
                pts.extend(legs)
        return unit_cand, np.array(pts), np.array(starts)


def _nearest_gated(tracks: dict[int, Track], xy: np.ndarray) -> int:
    """The track whose gate holds ``xy`` at the least distance, or -1."""
    best, best_d = -1, math.inf
    for tid, t in tracks.items():
        d = float(t.estimator.distance(xy[None], t.misses)[0])
        if d <= t.estimator.gate(t.misses) and d < best_d:
            best, best_d = tid, d
    return best
