"""Clusters of consecutive beams and the legs they make (thesis 3.4.1, 4.3.2).

Clustering by consecutive range jump (thesis 3.4.1, eq. 3-6: ``|r_k - r_{k-1}| < eps``); a
cluster never spans a "no return" beam. Clusters are two int arrays ``starts`` and ``ends``
(inclusive beam indices, ordered, disjoint); a detector keeps the clusters it likes with a
boolean mask over them. Per-cluster reductions use ``ufunc.reduceat`` over interleaved
``[start, end + 1]`` indices (so the beams between clusters never count): sums, minima,
centroids, end-to-end width (thesis eq. 4-6), inscribed angles.

Budget: a numpy call costs 1-8 us on the reference machine, so the hot path avoids full-scan
passes beyond the few needed to cluster, and works on per-cluster arrays afterwards.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from .beams import Beams
from .core import Prediction


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
