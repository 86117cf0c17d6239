"""Pure, vectorised helpers shared by every leg detector (no Zenoh; DESIGN.md "Leg candidates").

A detector turns one :class:`~followbot.schemas.LaserScan` into one
:class:`~followbot.schemas.PersonCandidates`. The steps most of them share live here, each a
function on numpy arrays:

* beam validity: NaN, +-inf, 0, ``< range_min_m`` and ``> range_max_m`` are "no return";
* polar -> cartesian in the scan's frame (REP-103: x forward, y left, angles counter-clockwise);
  the cos/sin tables are cached per scan geometry (a scanner's geometry never changes), and
  cartesian points are computed only for the beams a detector asks about;
* clustering by consecutive range jump (thesis 3.4.1, eq. 3-6: ``|r_k - r_{k-1}| < eps``); a
  cluster never spans a "no return" beam;
* per-cluster reductions with ``ufunc.reduceat`` over interleaved ``[start, end + 1]`` indices
  (so the beams between clusters never count): sums, minima, centroids, end-to-end width
  (thesis eq. 4-6), inscribed angles;
* leg pairing into persons (thesis 4.3.3) and the construction of the wire message.

Clusters are two int arrays ``starts`` and ``ends`` (inclusive beam indices, ordered, disjoint);
a detector keeps the clusters it likes with a boolean mask over them.

Budget: a numpy call costs 1-8 us on the reference machine, so the hot path avoids full-scan
passes beyond the few needed to cluster, and works on per-cluster arrays afterwards.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple, Protocol, runtime_checkable

import msgspec
import numpy as np

from followbot.schemas import Array, Candidate, Horizon, LaserScan, Leg, PersonCandidates
from followbot.services.common.geometry import wrap_angle
from followbot.services.common.scan import beam_geometry, valid_mask

__all__ = [
    "NO_RETURN",
    "PAIRINGS",
    "Anchor",
    "Beams",
    "Clusters",
    "LegDetector",
    "LegSet",
    "Prediction",
    "beam_geometry",
    "bridged",
    "candidates_message",
    "cluster_by_jump",
    "cluster_min",
    "cluster_sum",
    "detector_clip_m",
    "empty_candidates",
    "gate",
    "gate_xy",
    "horizon",
    "inscribed_angle_stats",
    "jump_cuts",
    "pair_legs",
    "paired_candidates",
    "prepare",
    "scan_reach_m",
    "valid_mask",
    "wrap_angle",
]

#: Optional tracked-target position (x_m, y_m) in the scan's frame (thesis criterion 3).
Prediction = tuple[float, float] | None

#: Range given to "no return" beams inside a detector: far below any real range, so a jump to
#: or from such a beam always splits clusters, and finite, so arithmetic on it stays finite.
NO_RETURN = -1.0e6

#: Most candidates one message may carry (schemas: MAX_ITEMS).
MAX_CANDIDATES = 256


@runtime_checkable
class LegDetector(Protocol):
    """What every detector offers: a ``name`` and ``detect``; settings are frozen Structs."""

    name: str

    def detect(self, scan: LaserScan, prediction: Prediction = None) -> PersonCandidates: ...


# --------------------------------------------------------------------------- beams


class Beams(msgspec.Struct, frozen=True):
    """One scan made ready for detection. Arrays ending in ``p`` carry one padding element
    after the last beam (for ``reduceat``); the others are views of them, one per beam."""

    rpp: np.ndarray
    """Ranges (m), float64, padded with :data:`NO_RETURN` at both ends (n + 2)."""
    valid: np.ndarray
    anglesp: np.ndarray
    cosp: np.ndarray
    sinp: np.ndarray
    increment_rad: float
    """|angular increment| between beams (rad)."""
    rawpp: np.ndarray | None = None
    """The measured ranges before clipping, padded like ``rpp`` (None: not clipped)."""

    @property
    def r(self) -> np.ndarray:
        """Ranges; :data:`NO_RETURN` where a beam has no return."""
        return self.rpp[1:-1]

    @property
    def rp(self) -> np.ndarray:
        return self.rpp[1:]

    @property
    def raw_rp(self) -> np.ndarray:
        """Measured (unclipped) ranges, one pad after the last beam: for leg positions."""
        return (self.rpp if self.rawpp is None else self.rawpp)[1:]

    @property
    def angles(self) -> np.ndarray:
        return self.anglesp[:-1]

    @property
    def cos(self) -> np.ndarray:
        return self.cosp[:-1]

    @property
    def sin(self) -> np.ndarray:
        return self.sinp[:-1]

    def xy(self, idx: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """Cartesian points of the beams ``idx`` (polar -> cartesian, scan frame)."""
        r = self.rpp[1:][idx]
        return r * self.cosp[idx], r * self.sinp[idx]

    @property
    def n(self) -> int:
        return int(self.valid.shape[0])


def prepare(scan: LaserScan, clip_range_m: float | None = None) -> Beams:
    """Ranges as float64 with "no return" beams set to :data:`NO_RETURN`; optional clipping.

    ``clip_range_m`` reproduces the thesis's setting (4.3.1: ranges beyond 3.5 m are set to
    3.5 m); clipped beams stay valid, at the clip range.
    """
    raw = scan.ranges_m()
    n = raw.shape[0]
    valid = valid_mask(raw, scan.range_min_m, scan.range_max_m)
    rpp = np.full(n + 2, NO_RETURN)
    r = rpp[1:-1]
    np.copyto(r, raw, where=valid)  # float32 -> float64 on the way
    rawpp = None
    if clip_range_m is not None:
        rawpp = rpp
        rpp = np.minimum(rpp, clip_range_m)
    angles, cos, sin = beam_geometry(
        float(scan.angle_min_rad), float(scan.angle_increment_rad), int(n)
    )
    return Beams(
        rpp=rpp,
        valid=valid,
        anglesp=angles,
        cosp=cos,
        sinp=sin,
        increment_rad=abs(float(scan.angle_increment_rad)) or math.radians(0.5),
        rawpp=rawpp,
    )


def polar_to_xy(r: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x = r cos(theta), y = r sin(theta) (REP-103)."""
    return r * np.cos(angles), r * np.sin(angles)


# --------------------------------------------------------------------------- clusters


class Clusters(msgspec.Struct, frozen=True):
    """Runs of consecutive valid beams: inclusive ``starts[i]..ends[i]``."""

    starts: np.ndarray
    ends: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        return self.ends - self.starts + 1

    def select(self, keep: np.ndarray) -> Clusters:
        return Clusters(self.starts[keep], self.ends[keep])

    def bounds(self) -> np.ndarray:
        """Interleaved ``[s0, e0 + 1, s1, e1 + 1, ...]`` for ``reduceat`` on a padded array."""
        out = np.empty(2 * self.starts.shape[0], dtype=np.intp)
        out[0::2] = self.starts
        out[1::2] = self.ends + 1
        return out

    def beams(self) -> tuple[np.ndarray, np.ndarray]:
        """Every beam of every cluster, and the cluster index of each (both 1-D)."""
        counts = self.counts
        k = counts.shape[0]
        cid = np.repeat(np.arange(k), counts)
        offsets = np.cumsum(counts) - counts
        idx = np.arange(cid.shape[0]) - offsets[cid] + self.starts[cid]
        return idx, cid

    def __len__(self) -> int:
        return int(self.starts.shape[0])


_EMPTY = np.zeros(0, dtype=np.intp)
_EMPTY.flags.writeable = False


def jump_cuts(rpp: np.ndarray, max_jump_m: float, bridge_m: float | None = None) -> np.ndarray:
    """Where runs start: indices k (0..n) with ``|rpp[k+1] - rpp[k]| >= max_jump_m``, for
    ranges ``rpp`` padded with :data:`NO_RETURN` (n + 2 long).

    ``bridge_m`` (beyond the thesis): a jump shorter than that is a cut only when it holds
    one beam farther on both sides, ``|r_{k+1} - r_{k-1}| >= max_jump_m`` and ``|r_k -
    r_{k-2}| >= max_jump_m`` (beams k-1 | k). An edge (a leg against what lies behind it)
    holds; a step of range noise inside a leg does not: with 15 mm noise per beam the
    difference of two beams exceeds 60 mm in ~0.5 % of the pairs, a leg at 1.5 m has ~9
    pairs, and a leg cut in two fails the point count and width tests (docs/laser_legs.md,
    "Noise inside a leg"). A beam without return always cuts, and jumps of bridge_m or more
    always cut (one background beam seen between two legs at one range stays a gap).
    """
    d = np.abs(np.diff(rpp))
    cut = np.flatnonzero(d >= max_jump_m)
    return bridged(rpp, d, cut, max_jump_m, bridge_m)


def bridged(
    rpp: np.ndarray, d: np.ndarray, cut: np.ndarray, max_jump_m: float, bridge_m: float | None
) -> np.ndarray:
    """``cut`` (the jumps ``d`` of at least ``max_jump_m``) without the jumps below
    ``bridge_m`` that do not hold one beam farther on both sides (:func:`jump_cuts`). Only
    those few jumps are looked at, in plain Python: the scan-long work stays one comparison."""
    if bridge_m is None or not bridge_m > max_jump_m or cut.shape[0] == 0:
        return cut
    soft = cut[d[cut] < bridge_m]
    if soft.shape[0] == 0:
        return cut
    # both beams of a soft jump return (a jump to NO_RETURN is never soft), so 1 <= k and
    # k + 1 <= n: rpp[k - 1] and rpp[k + 2] exist (a pad there is NO_RETURN: the jump holds)
    drop = [
        k
        for k in soft.tolist()
        if abs(float(rpp[k + 2]) - float(rpp[k])) < max_jump_m
        or abs(float(rpp[k + 1]) - float(rpp[k - 1])) < max_jump_m
    ]
    if not drop:
        return cut
    return cut[~np.isin(cut, drop)]


def cluster_by_jump(b: Beams, max_jump_m: float, bridge_m: float | None = None) -> Clusters:
    """Split the scan where ``|r_k - r_{k-1}| >= max_jump_m`` or a beam has no return
    (``bridge_m``: :func:`jump_cuts`).

    thesis 3.4.1 eq. 3-6 / 4.3.1: adjacent readings closer than 60 mm share a cluster.
    Beams without return carry :data:`NO_RETURN`, as do the pads before the first and after
    the last beam, so every jump to or from them is a cut and validity costs no extra pass.
    """
    # cut[i] = k: a run starts at beam k (k in 0..n); runs are cut[i] .. cut[i+1] - 1
    cut = jump_cuts(b.rpp, max_jump_m, bridge_m)
    starts = cut[:-1]
    keep = b.valid[starts]
    return Clusters(starts[keep], cut[1:][keep] - 1)


def cluster_sum(values: np.ndarray, c: Clusters) -> np.ndarray:
    """Sum of ``values`` per cluster; ``values`` needs one element past the last beam of the
    last cluster (e.g. ``Beams.rp``, ``Beams.cosp``)."""
    if len(c) == 0:
        return np.zeros(0)
    return np.add.reduceat(values, c.bounds())[0::2]


def cluster_min(values: np.ndarray, c: Clusters) -> np.ndarray:
    """Minimum of ``values`` per cluster; ``values`` needs one element past the last beam of
    the last cluster (pass ``Beams.rp``)."""
    if len(c) == 0:
        return np.zeros(0)
    return np.minimum.reduceat(values, c.bounds())[0::2]


def end_width(b: Beams, c: Clusters) -> np.ndarray:
    """End-to-end width, thesis eq. 4-6 ``W = sqrt(ra^2 + rb^2 - 2 ra rb cos(tb - ta))``."""
    ra, rb = b.r[c.starts], b.r[c.ends]
    cos = np.cos((c.ends - c.starts) * b.increment_rad)
    w2 = ra * ra + rb * rb - 2.0 * ra * rb * cos
    return np.sqrt(np.maximum(w2, 0.0, out=w2), out=w2)


def centroids(b: Beams, c: Clusters) -> tuple[np.ndarray, np.ndarray]:
    """Mean of each cluster's points (cartesian), from the measured (unclipped) ranges."""
    if len(c) == 0:
        z = np.zeros(0)
        return z, z
    bounds = c.bounds()
    cnt = c.counts
    rp = b.raw_rp
    xp = rp * b.cosp
    yp = rp * b.sinp
    return np.add.reduceat(xp, bounds)[0::2] / cnt, np.add.reduceat(yp, bounds)[0::2] / cnt


def inscribed_angle_stats(b: Beams, c: Clusters) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (rad) of the inscribed angles of every cluster.

    For each interior point P of a cluster with end points A and B the inscribed angle is APB
    (thesis 3.4.2 eq. 3-7; Xavier et al. 2005, cited by seed 003 IV). On a circular arc all are
    equal; a half circle gives 90 deg, a straight line 180 deg. Clusters of fewer than 3 points
    get mean pi and std inf.
    """
    k = len(c)
    if k == 0:
        z = np.zeros(0)
        return z, z
    idx, cid = c.beams()
    s, e = c.starts[cid], c.ends[cid]
    interior = (idx != s) & (idx != e)
    idx, s, e, cid = idx[interior], s[interior], e[interior], cid[interior]
    px, py = b.xy(idx)
    sx, sy = b.xy(s)
    ex, ey = b.xy(e)
    ax, ay = sx - px, sy - py
    bx, by = ex - px, ey - py
    ang = np.abs(np.arctan2(ax * by - ay * bx, ax * bx + ay * by))
    cnt = np.bincount(cid, minlength=k).astype(np.float64)
    sm = np.bincount(cid, weights=ang, minlength=k)
    sq = np.bincount(cid, weights=ang * ang, minlength=k)
    has = cnt > 0
    mean = np.full(k, math.pi)
    std = np.full(k, np.inf)
    mean[has] = sm[has] / cnt[has]
    std[has] = np.sqrt(np.maximum(sq[has] / cnt[has] - mean[has] ** 2, 0.0))
    return mean, std


# --------------------------------------------------------------------------- legs -> persons


class LegSet(msgspec.Struct, frozen=True):
    """Accepted legs of one scan, as parallel arrays."""

    x: np.ndarray
    y: np.ndarray
    first: np.ndarray
    last: np.ndarray
    width_m: np.ndarray

    @classmethod
    def from_clusters(cls, b: Beams, c: Clusters, width_m: np.ndarray) -> LegSet:
        """Legs at the centroid ("middle", thesis 4.3.3) of each cluster."""
        x, y = centroids(b, c)
        return cls(x, y, c.starts, c.ends, width_m)

    @classmethod
    def empty(cls) -> LegSet:
        z = np.zeros(0)
        return cls(z, z, _EMPTY, _EMPTY, z)

    def select(self, keep: np.ndarray) -> LegSet:
        return LegSet(*(getattr(self, f)[keep] for f in self.__struct_fields__))

    def __len__(self) -> int:
        return int(self.x.shape[0])


def gate(legs: LegSet, prediction: Prediction, radius_m: float) -> np.ndarray:
    """Mask of the legs within ``radius_m`` of ``prediction`` (every leg when it is None or
    not finite)."""
    return gate_xy(legs.x, legs.y, prediction, radius_m)


def gate_xy(x: np.ndarray, y: np.ndarray, prediction: Prediction, radius_m: float) -> np.ndarray:
    """Mask of the points (x, y) within ``radius_m`` of ``prediction`` (every point when it is
    None or not finite): criterion 3's distance rule, for legs or persons' centres."""
    if prediction is None:
        return np.ones(len(x), dtype=bool)
    px, py = float(prediction[0]), float(prediction[1])
    if not (math.isfinite(px) and math.isfinite(py)):
        return np.ones(len(x), dtype=bool)
    return np.hypot(np.asarray(x) - px, np.asarray(y) - py) < radius_m


#: Pairing rules (``pairing`` settings): the thesis's greedy one, or the best matching.
PAIRINGS = ("closest_first", "matching")

#: Beyond this many legs within reach of each other, ``matching`` falls back to closest first
#: (the exact search grows exponentially; a scan's group of touching legs is 2-6).
MAX_MATCHED_GROUP = 12


class Anchor(NamedTuple):
    """Where the tracked target should be, for :func:`pair_legs` (``matching``) to prefer the
    grouping of legs that has a person there (beyond the thesis; the ``thesis`` detector's
    ``anchor_weight``)."""

    x_m: float
    y_m: float
    weight: float
    """Metres of pair weight (``max_distance_m - d``) one metre nearer the anchor is worth."""
    gate_m: float
    """Persons farther than this from the anchor count as this far (criterion 3's gate): far
    from the target, the anchor prefers nothing."""
    lone_leg_m: float
    """A lone leg's distance to the anchor counts this much less: a person's centre lies
    about half a stride from a leg seen alone."""


def pair_legs(
    x: list[float],
    y: list[float],
    max_distance_m: float,
    pairing: str = "closest_first",
    anchor: Anchor | None = None,
) -> list[tuple[int, ...]]:
    """Group legs into persons, each leg used once; ``(i, j)`` for two legs closer than
    ``max_distance_m`` and ``(i,)`` for a lone leg, ordered by their first leg.

    ``closest_first`` (thesis 4.3.3): the closest pair first, then the closest of the rest.
    ``matching`` (beyond the thesis): the pairing that maximises the sum over pairs of
    ``max_distance_m - d``, i.e. every pair counts, the tighter the better. Two people walking
    0.35 m apart show four legs where an inner leg of each is closer to the other person's
    than to its own partner: closest first pairs the two inner legs into a phantom person
    between them and leaves the outer legs alone; the matching keeps both people. Exact per
    group of legs within reach of each other (up to :data:`MAX_MATCHED_GROUP` legs).

    ``anchor`` (``matching`` only): the tracked target's predicted position. The grouping then
    maximises the pair weights minus ``anchor.weight`` times the distance from the anchor to
    the nearest person of the grouping (see :class:`Anchor`). When a passer-by walks just in
    front of the target, the target's far leg is hidden behind the passer-by's near leg, and
    that leg is often closer to the target's near leg than to the passer-by's far leg: the
    matching alone then pairs the two people's near legs (a cross pair ~0.2 m off the target,
    towards the passer-by); with the anchor it keeps the passer-by's legs together and the
    target's near leg alone, where the target is.

    Plain Python: a scan has a handful of legs, and numpy's per-call cost would dominate.
    """
    k = len(x)
    pairs = []
    for i in range(k):
        xi, yi = x[i], y[i]
        for j in range(i + 1, k):
            d = math.hypot(x[j] - xi, y[j] - yi)
            if d < max_distance_m:
                pairs.append((d, i, j))
    if pairing not in PAIRINGS:
        raise ValueError(f"pairing must be one of {PAIRINGS}, not {pairing!r}")
    ends = [i for _, i, _ in pairs] + [j for _, _, j in pairs]
    if len(set(ends)) == len(ends):
        # no leg with two partners in reach: every rule (and every anchor) pairs them all
        chosen = [(i, j) for _, i, j in pairs]
    elif pairing == "matching":
        chosen = _best_matching(k, pairs, max_distance_m)
        if anchor is not None:
            chosen = _anchored(x, y, k, pairs, chosen, max_distance_m, anchor)
    else:
        chosen = _closest_first(k, sorted(pairs))
    paired = {i for pair in chosen for i in pair}
    return sorted([*chosen, *((i,) for i in range(k) if i not in paired)])


#: Most legs near the anchor whose groupings :func:`pair_legs` enumerates (an anchor among
#: more leaves the plain matching; 8 legs have at most 764 groupings, a scan's 2-4 a handful).
MAX_ANCHORED_LEGS = 8


def _anchored(
    x: list[float],
    y: list[float],
    k: int,
    pairs: list[tuple[float, int, int]],
    chosen: list[tuple[int, int]],
    max_distance_m: float,
    a: Anchor,
) -> list[tuple[int, int]]:
    """The grouping maximising the pair weights minus ``a.weight`` times the distance from the
    anchor to its nearest person (capped at ``a.gate_m``), among those with at least as many
    pairs as ``chosen`` (the plain best matching), which stays unless another grouping scores
    higher. The anchor only chooses *which* legs pair, never fewer pairs: splitting a person's
    own two legs because the prediction lags towards one of them biased every track (RMSE up
    in all 15 scenarios).

    Exact: every grouping of the legs within reach (transitively) of a leg that can belong to
    a person inside the gate is scored; the other legs keep ``chosen``'s grouping. More than
    :data:`MAX_ANCHORED_LEGS` such legs, or none with two partners in reach (no other
    grouping then has as many pairs): ``chosen``."""
    weight = {(i, j): max_distance_m - d for d, i, j in pairs}
    near: list[list[int]] = [[] for _ in range(k)]
    for _, i, j in pairs:
        near[i].append(j)
        near[j].append(i)

    def cost(person: tuple[int, ...]) -> float:
        if len(person) == 2:
            i, j = person
            d = math.hypot((x[i] + x[j]) / 2 - a.x_m, (y[i] + y[j]) / 2 - a.y_m)
        else:
            d = max(0.0, math.hypot(x[person[0]] - a.x_m, y[person[0]] - a.y_m) - a.lone_leg_m)
        return min(d, a.gate_m)

    # the legs whose grouping can put a person inside the gate, and all legs in reach of them
    reach = a.gate_m + max(max_distance_m / 2, a.lone_leg_m)
    todo = [i for i in range(k) if math.hypot(x[i] - a.x_m, y[i] - a.y_m) < reach]
    group = set(todo)
    while todo:
        for j in near[todo.pop()]:
            if j not in group:
                group.add(j)
                todo.append(j)
    if len(group) > MAX_ANCHORED_LEGS or all(len(near[i]) < 2 for i in group):
        return chosen
    outside = [g for g in chosen if g[0] not in group]
    paired = {i for g in chosen for i in g}
    rest = [*outside, *((i,) for i in range(k) if i not in group and i not in paired)]
    nearest_outside = min((cost(g) for g in rest), default=a.gate_m)
    inside = [g for g in chosen if g[0] in group]

    def value(groups: list[tuple[int, int]]) -> float:
        legs = {i for g in groups for i in g}
        lone = [(i,) for i in group if i not in legs]
        nearest = min([nearest_outside, *(cost(g) for g in groups), *(cost(g) for g in lone)])
        return sum(weight[g] for g in groups) - a.weight * nearest

    def groupings(free: list[int]):
        """Every grouping of the legs ``free`` (ascending) into pairs in reach and lone legs."""
        if not free:
            yield []
            return
        i, others = free[0], free[1:]
        yield from groupings(others)  # i alone
        for j in near[i]:
            if j in others:
                for g in groupings([m for m in others if m != j]):
                    yield [(i, j), *g]

    best, best_value = inside, value(inside)
    for g in groupings(sorted(group)):
        if len(g) >= len(inside):
            v = value(g)
            if v > best_value + 1e-12:
                best, best_value = g, v
    return [*outside, *best]


def _closest_first(k: int, pairs: list[tuple[float, int, int]]) -> list[tuple[int, int]]:
    used = [False] * k
    out = []
    for _, i, j in pairs:
        if not used[i] and not used[j]:
            used[i] = used[j] = True
            out.append((i, j))
    return out


def _best_matching(
    k: int, pairs: list[tuple[float, int, int]], max_distance_m: float
) -> list[tuple[int, int]]:
    """Maximum-weight matching (weight ``max_distance_m - d``), exact per connected group."""
    near: list[list[tuple[int, float]]] = [[] for _ in range(k)]
    for d, i, j in pairs:
        w = max_distance_m - d
        near[i].append((j, w))
        near[j].append((i, w))
    seen = [False] * k
    out: list[tuple[int, int]] = []
    for root in range(k):
        if seen[root] or not near[root]:
            continue
        group, stack = [], [root]  # the legs within reach of root, transitively
        seen[root] = True
        while stack:
            i = stack.pop()
            group.append(i)
            for j, _ in near[i]:
                if not seen[j]:
                    seen[j] = True
                    stack.append(j)
        if len(group) > MAX_MATCHED_GROUP:
            inside = set(group)
            out += _closest_first(k, sorted(p for p in pairs if p[1] in inside))
            continue
        out += _match_group(sorted(group), near)
    return out


def _match_group(
    group: list[int], near: list[list[tuple[int, float]]]
) -> tuple[tuple[int, int], ...]:
    """The best matching of one group of legs: each leg, lowest first, alone or paired."""
    if len(group) == 2:  # the common case: one pair
        return ((group[0], group[1]),)
    bit = {leg: b for b, leg in enumerate(group)}
    memo: dict[int, tuple[float, tuple[tuple[int, int], ...]]] = {0: (0.0, ())}

    def best(free: int) -> tuple[float, tuple[tuple[int, int], ...]]:
        if free in memo:
            return memo[free]
        b = (free & -free).bit_length() - 1  # the lowest free leg: alone, or paired
        rest = free & ~(1 << b)
        score, chosen = best(rest)
        i = group[b]
        for j, w in near[i]:
            if free >> bit[j] & 1:
                sub, sub_chosen = best(rest & ~(1 << bit[j]))
                if sub + w > score:
                    score, chosen = sub + w, ((min(i, j), max(i, j)), *sub_chosen)
        memo[free] = score, chosen
        return score, chosen

    return best((1 << len(group)) - 1)[1]


def horizon(scan: LaserScan, bin_rad: float = math.radians(1.0)) -> Horizon:
    """The nearest return of ``scan`` in bearing bins of ``bin_rad`` (the scan's own resolution
    when coarser), ascending bearings whatever the scan's direction; +inf in a bin where no beam
    returned (NaN, inf, 0 and out-of-range beams). Beam ``i`` covers
    ``angle_min + (i -+ 1/2) * increment``; the bins start where the first beam does."""
    r = scan.ranges.numpy()
    n = r.shape[0]
    inc = float(scan.angle_increment_rad)
    a0 = float(scan.angle_min_rad)
    if inc < 0:  # bearings descending: the same beams read the other way round
        r = r[::-1]
        a0 += inc * (n - 1)
        inc = -inc
    rr = np.where(valid_mask(r, scan.range_min_m, scan.range_max_m), r, np.inf)
    if n == 1:  # one beam (its increment may be 0): one bin centred on it
        inc = bin_rad
    width = max(bin_rad, inc)
    bins, first, where = _horizon_bins(n, inc, width)
    out = np.full(bins, np.inf, dtype=np.float32)
    out[where] = np.minimum.reduceat(rr, first)
    return Horizon(
        angle_min_rad=wrap_angle(a0 - inc / 2),
        increment_rad=width,
        ranges=Array.from_numpy(out),
    )


@functools.lru_cache(maxsize=16)
def _horizon_bins(n: int, inc: float, width: float) -> tuple[int, np.ndarray, np.ndarray]:
    """(bins, first beam of each bin that has beams, that bin's index) of a scan geometry."""
    bins = max(1, min(math.ceil(n * inc / width - 1e-9), math.floor(2 * math.pi / width + 1e-9)))
    idx = np.minimum(((np.arange(n) + 0.5) * (inc / width)).astype(np.intp), bins - 1)
    first = np.flatnonzero(np.concatenate(([True], idx[1:] != idx[:-1])))
    return bins, first, idx[first]


def detector_clip_m(detector: object) -> float | None:
    """The range beyond which ``detector`` finds no one: its settings' clip_range_m, also
    through a wrapper's ``inner`` detector (None: it clips nothing). Fixed for a detector's
    life, so asked once, not per scan."""
    while not hasattr(detector, "settings") and hasattr(detector, "inner"):
        detector = detector.inner
    clip = getattr(getattr(detector, "settings", None), "clip_range_m", None)
    return None if clip is None else float(clip)


def scan_reach_m(clip_m: float | None, scan: LaserScan) -> float | None:
    """PersonCandidates.reach_m on ``scan`` of a detector clipping at ``clip_m``
    (:func:`detector_clip_m`): the clip or the scan's range_max_m, whichever is nearer; None
    when neither is a positive finite range."""
    reach = [r for r in (clip_m, float(scan.range_max_m)) if r is not None]
    reach = [r for r in reach if math.isfinite(r) and r > 0.0]
    return min(reach) if reach else None


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


def paired_candidates(
    scan: LaserScan,
    detector: str,
    legs: LegSet | list[Leg],
    pair_distance_m: float,
    two_leg_confidence: float,
    one_leg_confidence: float,
    partner: Callable[[list[Leg], int], Leg | None] | None = None,
    pairing: str = "closest_first",
    anchor: Anchor | None = None,
) -> PersonCandidates:
    """Pair ``legs`` (thesis 4.3.3) and wrap the persons as the wire message. ``partner``:
    given the legs and a lone leg's index, another leg to pair it with, or None (a detector
    that finds legs the pairing cannot, e.g. a half-hidden one); ``pairing``: see
    :func:`pair_legs`, as ``anchor``. ``legs`` as wire structs are used as they are (not
    copied)."""
    wire = legs if isinstance(legs, list) else leg_list(legs)
    groups = pair_legs(
        [w.x_m for w in wire], [w.y_m for w in wire], pair_distance_m, pairing, anchor
    )
    out = []
    for g in groups:
        other = None if len(g) == 2 or partner is None else partner(wire, g[0])
        if len(g) == 2:
            out.append(person([wire[i] for i in g], "two_legs", two_leg_confidence))
        elif other is not None:
            out.append(person([wire[g[0]], other], "two_legs", two_leg_confidence))
        else:
            out.append(person([wire[g[0]]], "one_leg", one_leg_confidence))
    return candidates_message(scan, detector, out)
