"""A learned leg classifier: random trees (OpenCV ``cv2.ml.RTrees``) on segment features —
beyond the seeds. In the spirit of Arras et al. (ICRA 2007) and the leg_tracker
project whose recordings we evaluate on; our own feature set and code.

1. Segments (:func:`segments`): runs of consecutive valid beams whose neighbouring points are
   closer than ``cluster_gap_m`` (Euclidean, so the criterion means the same at any range),
   with ``min_points`` or more points and an end-to-end width up to ``max_width_m``.
2. Features of each segment (:data:`FEATURES`, :func:`segment_features`), all computed for
   every segment at once with numpy (no loop over segments):

   * shape: point count, end-to-end width, range of the centroid, RMS and mean distance to
     the centroid, line-fit residual (square root of the scatter matrix's minor eigenvalue),
     axis ratio, Kasa circle fit (radius capped at 1 m, RMS residual), boundary length and
     regularity (std of the point-to-point steps), inscribed angles (mean, std), chord depth
     (mean and largest signed distance of the points from the chord, positive towards the
     laser: a leg bulges towards it, a room corner away), obliqueness (width over the arc the
     beams sweep at that range: 1 for a surface facing the laser, more for a grazing one);
   * background and occlusion: the range steps to the beams just outside the segment on both
     sides (positive: background behind; negative: something in front, the segment is partly
     occluded), as the smaller and the larger of the two so that the laser's turning direction
     does not matter (a beam without return counts as far, steps capped at ±2 m);
   * context: distance to the nearest other segment, its width and point count, how many
     segments lie within 1 m and within 0.6 m, and — when the nearest segment lies within
     0.6 m, a possible second leg — its circle and line residuals, radius, chord depth,
     larger background step and range difference (else sentinel values). (No free-space
     features — distance to the nearest other scan point, points within 0.5 m: they describe
     the room's layout around the segment, and in cross-validation on rooms left out of
     training they raised the false persons; ``train.py``.)

3. Optionally (``background_memory_s``), a segment on static background — seen occupied again
   and again over the last seconds by the same laser, scans registered by the laser's
   odometry pose when ``detect`` is given one (``pose``), else by ICP (:mod:`..background`) —
   loses ``background_penalty`` of its vote share: furniture legs and
   clutter stay put, walking legs do not. The detector is then stateful: it expects the scans
   of one stream in order (a new size, frame, a stamp going back or a gap starts afresh).

4. Optionally (``track_memory_s``), temporal confirmation (:class:`LegTracks`): short-lived
   leg tracks in the registered frame of step 3 (when the background is off: the odometry
   frame of the given pose, else the laser frame)
   carry an evidence ``e``, a running mean of the scores of the segments they took up. A
   segment's score becomes ``w·s + (1 − w)·e`` with ``e`` the evidence of the track it
   continues (0 for a new track): a leg seen over several scans keeps its score, a blob that
   flickers up in one scan keeps only ``w`` of it. With this stage the detector is stateful
   too (same resets as step 3).

5. The forest's vote share for "leg" (after steps 3 and 4) is each segment's score. Legs are
   paired as in the thesis (500 mm, closest first) among the segments scoring at least
   ``min(threshold, pair_threshold)``; a two-leg person is kept when both its legs score
   ``pair_threshold`` or more, a single leg (also one of a rejected pair) when it scores
   ``threshold`` or more. So a weaker leg is accepted next to a second leg, and a lone strong
   leg is still a person candidate. Both thresholds are chosen by ``train.py`` with
   cross-validation inside the training split.

The model file ships with the package (``services/laser_legs/models/``); it is produced by
``python -m followbot.research.train`` (reproducible: fixed seeds, documented data
split). ``model_path`` selects another file.
"""

from __future__ import annotations

import functools
import math
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import msgspec
import numpy as np

from followbot.schemas import LaserScan, Leg, PersonCandidates
from followbot.services.common.scan import beam_geometry, valid_mask

from ..background import StaticBackground
from ..core import LaserPose, Prediction
from ..message import candidates_message, person
from ..pairing import pair_legs

__all__ = [
    "FEATURES",
    "LearnedSettings",
    "LegTracks",
    "RandomTreesLegDetector",
    "Segments",
    "default_model_path",
    "features_and_centroids",
    "full_circle",
    "segment_features",
    "segments",
]

FEATURES = (
    "n_points",
    "width_m",
    "range_m",
    "rms_spread_m",
    "mean_spread_m",
    "line_residual_m",
    "axis_ratio",
    "circle_radius_m",
    "circle_residual_m",
    "boundary_length_m",
    "boundary_regularity_m",
    "inscribed_mean_rad",
    "inscribed_std_rad",
    "chord_depth_m",
    "chord_depth_max_m",
    "obliqueness",
    "step_min_m",
    "step_max_m",
    "neighbour_distance_m",
    "neighbour_width_m",
    "neighbour_points",
    "segments_within_1m",
    "segments_within_0_6m",
    "neighbour_circle_residual_m",
    "neighbour_line_residual_m",
    "neighbour_circle_radius_m",
    "neighbour_chord_depth_m",
    "neighbour_step_max_m",
    "neighbour_range_diff_m",
)

#: Range steps to the neighbouring beams are capped here (a beam without return counts as far).
STEP_CAP_M = 2.0
#: Context distances are capped here.
CONTEXT_CAP_M = 3.0
#: A nearest segment closer than this is described by the ``neighbour_*`` shape features.
PARTNER_M = 0.6
#: Circle radii are capped here (a straight segment's fit runs away).
RADIUS_CAP_M = 1.0
OBLIQUENESS_CAP = 10.0
#: neighbour_* shape features when no segment lies within PARTNER_M.
_NO_PARTNER = np.array([[-1.0], [-1.0], [-1.0], [-1.0], [-CONTEXT_CAP_M], [-CONTEXT_CAP_M]])

MODEL_FILE = "learned_rtrees.yml.gz"


def default_model_path() -> Path:
    return Path(str(resources.files("followbot.services.laser_legs") / "models" / MODEL_FILE))


class LearnedSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`RandomTreesLegDetector`.

    The thresholds were chosen by ``train.py`` for the shipped model (cross-validation inside
    the training split: the fewest false persons per scan at a leg recall of 0.92 or more), as
    were the background settings; a model trained with other features or data needs its own.
    """

    model_path: str = ""  # "" = the model shipped with the package
    # thresholds chosen with the background and track settings below by train.py's rule
    # --min-recall 0.92 (the fewest validation false persons at >= 0.92 validation recall;
    # the background chosen again under the tracks; docs/laser_legs.md, which also compares
    # evaluate's variants `learned_maxrecall`, `learned_notrack` and `learned_nobg`)
    threshold: float = 0.10  # score for a one-leg person (train.py, cross-validation)
    pair_threshold: float = 0.05  # score of both legs of a two-leg person (same)
    cluster_gap_m: float = 0.13  # not in the seeds (leg_tracker's cluster distance)
    min_points: int = 3
    """Segments of fewer points are not classified (at least 3: the features need them)."""
    max_width_m: float = 0.6
    """Segments wider end to end than this (m) are not classified (two legs together fit)."""
    max_range_m: float | None = 8.0
    """Returns beyond this range (m) are not classified (they still cut segments and count as
    background behind a segment); None: up to the scanner's range_max_m. Not in the seeds (the
    thesis clips at 3.5 m; issue 35: a person is found out to 8 m)."""
    dropout_beams: int = 3
    """Up to this many consecutive beams without return (NaN, inf, 0, out of the sensor's
    limits) between two points closer than ``cluster_gap_m`` do not cut a segment: a sparse leg
    seen with dropouts stays one segment (issue 35; 0: every such beam cuts). Segments touching
    the first or last beam (within this many beams) of a scan that is not a full circle are
    cut by the edge of the view and never classified; on a full circle the two ends join."""
    pair_distance_m: float = 0.500  # thesis 4.3.3
    gate_m: float = 0.400  # thesis 4.3.2 criterion 3, when a prediction is given
    # static background (background.py; not in the seeds): a segment seen occupied in at least
    # background_static_fraction of at least background_min_views views over the last
    # background_memory_s seconds loses background_penalty of its vote share. None or 0: off.
    background_memory_s: float | None = 2.0  # train.py, cross-validation
    background_static_fraction: float = 0.8  # train.py, cross-validation
    background_penalty: float = 0.15
    """A static segment's loss of vote share (1: never a leg). train.py's cross-validation chose
    0.3; at 0.3 a person standing still for the background's memory drops out (in the
    simulator the target standing while vision learns it was never acquired, tracked 0 %), at
    0.15 they stay (tracked 91.6 %) and the held-out negatives still give no false person
    through the tracker (docs/laser_legs.md, "Issue 35, the standing person")."""
    background_min_views: int = 5  # a choice: ~0.7 s of a 7.5 Hz laser
    background_hit_m: float = 0.15  # a choice: leg radius + matching error
    background_ego_motion: bool = True
    """Scans that come without the laser's pose (no odometry at their stamp) are registered
    to each other by ICP; False: such a scan is taken as seen from where the previous one
    was (a still laser). A pose from odometry is used whenever the stage has one."""
    # temporal confirmation (LegTracks; not in the seeds): a segment's score becomes
    # track_weight * score + (1 - track_weight) * the evidence of the leg track it continues
    # (a running mean of its scores with time constant track_memory_s; 0 for a new track).
    # None or 0: off (scores as they are).
    track_memory_s: float | None = 0.8  # train.py, cross-validation
    track_weight: float = 0.2  # train.py, cross-validation (1: off)
    track_velocity: bool = True  # train.py, cross-validation (predict tracks at their speed)
    track_gate_m: float = 0.3  # a choice: a labelled leg moves <= 0.18-0.42 m between scans (95 %)
    track_max_gap_s: float = 0.5  # a choice: a longer pause between scans drops the tracks

    def __post_init__(self) -> None:
        for name in ("threshold", "pair_threshold", "background_static_fraction", "track_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1]")
        if self.background_memory_s is not None and not self.background_memory_s >= 0:
            raise ValueError("background_memory_s must be >= 0 (or None: off)")
        m = self.track_memory_s
        if m is not None and not (m >= 0 and math.isfinite(m)):
            raise ValueError("track_memory_s must be finite and >= 0 (or None: off)")
        for name in ("track_gate_m", "track_max_gap_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if not self.background_penalty >= 0:
            raise ValueError("background_penalty must be >= 0")
        if self.background_min_views < 1:
            raise ValueError("background_min_views must be >= 1")
        if not self.background_hit_m > 0:
            raise ValueError("background_hit_m must be > 0")
        if self.min_points < 3:
            raise ValueError("min_points must be >= 3")
        if self.dropout_beams < 0:
            raise ValueError("dropout_beams must be >= 0")
        if self.max_range_m is not None and not self.max_range_m > 0:
            raise ValueError("max_range_m must be > 0 (or None: the scanner's range)")
        for name in ("cluster_gap_m", "max_width_m", "gate_m", "pair_distance_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")


class Segments(NamedTuple):
    """Segments of one scan over its *points* (the returns used, in beam order; on a full
    circle rotated so that no segment wraps inside the arrays).

    ``starts``/``ends`` are inclusive point indices; ``x``, ``y``, ``r`` and ``beam`` (the beam
    index) are per point; ``outer`` (2, k) is the range of the beam just before each segment's
    first beam and just after its last (+inf where that beam has no return or lies off the
    scan)."""

    starts: np.ndarray
    ends: np.ndarray
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    outer: np.ndarray
    beam: np.ndarray


def _no_segments() -> Segments:
    z, e = np.zeros(0), np.zeros(0, dtype=np.intp)
    return Segments(e, e, z, z, z, np.zeros((2, 0)), e)


def full_circle(n: int, increment_rad: float) -> bool:
    """True when ``n`` beams of ``increment_rad`` cover 360 deg: the last beam and the first are
    neighbours."""
    return n > 2 and abs(abs(increment_rad) * n - 2.0 * math.pi) < 0.5 * abs(increment_rad)


def segments(
    scan: LaserScan,
    cluster_gap_m: float = 0.13,
    min_points: int = 3,
    max_width_m: float = 0.6,
    max_range_m: float | None = None,
    dropout_beams: int = 0,
) -> Segments:
    """Segments of one scan: runs of returns whose neighbouring points are closer than
    ``cluster_gap_m``.

    * returns beyond ``max_range_m`` are not points; they cut (something far was seen there);
    * up to ``dropout_beams`` consecutive beams without return (NaN, inf, 0, out of the
      sensor's limits) between two points closer than ``cluster_gap_m`` do not cut: a sparse
      leg seen with dropouts stays one segment;
    * a segment touching the first or last beam of a scan that is not a full circle is cut by
      the edge of the view (a wall end, or half a leg) and left out; on a full circle the last
      beam and the first are neighbours and a segment may run across them.
    """
    raw = scan.ranges_m()
    n = raw.shape[0]
    ret = valid_mask(raw, scan.range_min_m, scan.range_max_m) & np.isfinite(raw)
    use = ret if max_range_m is None else ret & (raw <= max_range_m)
    beam = use.nonzero()[0]
    m = beam.shape[0]
    if m < min_points:
        return _no_segments()
    inc = float(scan.angle_increment_rad)
    _, cos, sin = beam_geometry(float(scan.angle_min_rad), inc, n)
    r = raw[beam].astype(np.float64)
    x = r * cos[beam]
    y = r * sin[beam]
    circle = full_circle(n, inc)
    # join[i]: point i and the next one (cyclic) lie in one segment
    nxt = np.arange(1, m + 1)
    nxt[-1] = 0
    gap = beam[nxt] - beam
    gap[-1] += n
    dx = x[nxt] - x
    dy = y[nxt] - y
    join = (dx * dx + dy * dy < cluster_gap_m * cluster_gap_m) & (gap <= dropout_beams + 1)
    if dropout_beams and max_range_m is not None:
        far = np.zeros(n + 1, dtype=np.int32)  # returns beyond max_range_m before each beam
        np.cumsum(ret & ~use, out=far[1:])
        between = far[beam[nxt]] - far[beam + 1]  # over the beams between a point and the next
        between[-1] += far[n]  # the last point's next is the first (across the scan's end)
        join &= between == 0
    if not circle:
        join[-1] = False
    elif join.all():  # one closed ring round the laser: a wall
        return _no_segments()
    else:  # rotate so that the arrays start just after a cut
        shift = int((~join).nonzero()[0][0]) + 1
        if shift < m:
            order = np.arange(shift, shift + m)  # a rotation by shift (one take per array)
            order[m - shift :] -= m
            beam, x, y, r, join = (a.take(order) for a in (beam, x, y, r, join))
    cut = (~join).nonzero()[0]  # the last point of each segment
    ends = cut
    starts = np.empty_like(cut)
    starts[0] = 0
    starts[1:] = cut[:-1] + 1
    keep = ends - starts + 1 >= min_points
    if not circle:  # cut by the edge of the view
        keep &= (beam[starts] > dropout_beams) & (beam[ends] < n - 1 - dropout_beams)
    starts, ends = starts[keep], ends[keep]
    keep = np.hypot(x[ends] - x[starts], y[ends] - y[starts]) <= max_width_m
    starts, ends = starts[keep], ends[keep]
    around = np.array([beam[starts] - 1, beam[ends] + 1])
    if circle:
        around %= n
    outside = (around < 0) | (around >= n)
    around = np.clip(around, 0, n - 1)
    outer = np.where(ret[around] & ~outside, raw[around], np.inf)
    return Segments(starts, ends, x, y, r, outer, beam)


def segment_features(seg: Segments) -> np.ndarray:
    """(k, len(FEATURES)) float32 features of the segments (see the module docstring)."""
    return features_and_centroids(seg)[0]


def features_and_centroids(seg: Segments):
    """Features and centroids (cx, cy) of the segments.

    Every per-point quantity is one row of a stacked array and the segments' sums are one
    ``np.add.reduceat`` over the segments' (contiguous) points: the cost is a fixed number of
    numpy calls whatever the number of segments."""
    starts, ends, x, y, r = seg.starts, seg.ends, seg.x, seg.y, seg.r
    k = int(starts.shape[0])
    if k == 0:
        z = np.zeros(0)
        return np.zeros((0, len(FEATURES)), dtype=np.float32), z, z
    p = _gather(starts, ends, x, y)
    m = _moments(p)
    line_res, axis_ratio = _line_fit(m)
    ax, ay, ex, ey = x[starts], y[starts], x[ends], y[ends]
    wx, wy = ex - ax, ey - ay
    width = np.hypot(wx, wy)
    radius, circ_res, depth, depth_max, ia_mean, ia_std = _shape_sums(p, m, line_res, width)
    rng = np.hypot(m.cx, m.cy)
    # the arc the beams sweep at that range: the angle between the end points' bearings
    # ((points - 1) x the beam spacing on a run without dropouts)
    sweep = np.abs(np.arctan2(ax * ey - ay * ex, ax * ex + ay * ey))
    obliq = np.minimum(width / np.maximum(sweep * rng, 1e-6), OBLIQUENESS_CAP)
    step_min, step_max = _background_steps(r, seg.outer, starts, ends)
    cols = [p.fc, width, rng, np.sqrt(m.tr), m.mean_spread, line_res, axis_ratio, radius, circ_res]
    cols += [m.blen, m.breg, ia_mean, ia_std, depth, depth_max, obliq, step_min, step_max]
    partner_shape = np.array([circ_res, line_res, radius, depth, step_max, rng])
    cols += _context(m.cx, m.cy, width, p.fc, partner_shape)
    return _rows(cols, k), m.cx, m.cy


class _Points(NamedTuple):
    """Every point of every segment, gathered in one array (segments are disjoint, ordered)."""

    k: int
    fc: np.ndarray
    """(k,) points per segment, as floats."""
    cid: np.ndarray
    """Segment index of each point."""
    first: np.ndarray
    """(k,) offset of each segment's first point in the gathered arrays."""
    last: np.ndarray
    """(k,) offset of each segment's last point."""
    px: np.ndarray
    py: np.ndarray


def _gather(starts, ends, x, y) -> _Points:
    k = int(starts.shape[0])
    cnt = ends - starts + 1
    cid = np.repeat(np.arange(k), cnt)
    last = np.cumsum(cnt) - 1
    first = last - cnt + 1
    idx = np.arange(cid.shape[0]) + (starts - first)[cid]  # the points' indices in x, y
    return _Points(k, cnt.astype(np.float64), cid, first, last, x[idx], y[idx])


class _Moments(NamedTuple):
    """Centroids, the points about them, and per-segment sums."""

    cx: np.ndarray
    cy: np.ndarray
    u: np.ndarray
    """Per point: x about its segment's centroid."""
    v: np.ndarray
    suu: np.ndarray
    svv: np.ndarray
    suv: np.ndarray
    mean_spread: np.ndarray
    """Mean distance of the points to the centroid."""
    tr: np.ndarray
    """Trace of the scatter matrix [suu suv; suv svv] (the mean squared spread)."""
    det: np.ndarray
    """Its determinant."""
    bu: np.ndarray
    bv: np.ndarray
    """Half the means of u (u^2 + v^2) and v (u^2 + v^2) (the circle fit's right-hand side)."""
    blen: np.ndarray
    """Boundary length: the sum of the point-to-point steps."""
    breg: np.ndarray
    """Boundary regularity: the standard deviation of the steps."""


def _moments(p: _Points) -> _Moments:
    fc, cid, first = p.fc, p.cid, p.first
    c = np.add.reduceat(np.stack([p.px, p.py]), first, axis=1) / fc
    cx, cy = c[0], c[1]
    u = p.px - cx[cid]
    v = p.py - cy[cid]
    q = np.empty((8, u.shape[0]))
    uu, vv = np.multiply(u, u, out=q[0]), np.multiply(v, v, out=q[1])
    np.multiply(u, v, out=q[2])
    zz = uu + vv
    np.sqrt(zz, out=q[3])
    np.multiply(u, zz, out=q[4])
    np.multiply(v, zz, out=q[5])
    # the steps from each point to the next in its segment (0 into a segment's first point)
    step2 = q[7]
    step2[0] = 0.0
    np.add(np.square(p.px[1:] - p.px[:-1]), np.square(p.py[1:] - p.py[:-1]), out=step2[1:])
    step2[first] = 0.0
    np.sqrt(step2, out=q[6])
    sums = np.add.reduceat(q, first, axis=1)
    suu, svv, suv, spread = sums[:4] / fc
    bu, bv = 0.5 * sums[4:6] / fc
    nstep = fc - 1.0
    blen = sums[6]
    bmean = blen / nstep
    breg = np.sqrt(np.maximum(sums[7] / nstep - bmean * bmean, 0.0))
    tr = suu + svv
    det = suu * svv - suv * suv
    return _Moments(cx, cy, u, v, suu, svv, suv, spread, tr, det, bu, bv, blen, breg)


def _line_fit(m: _Moments) -> tuple[np.ndarray, np.ndarray]:
    """(line-fit residual, axis ratio) of each segment."""
    # scatter matrix eigenvalues: lam2 is the line fit's mean squared residual
    tr, det = m.tr, m.det
    disc = np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))
    lam1 = 0.5 * tr + disc
    lam2 = np.maximum(0.5 * tr - disc, 0.0)
    return np.sqrt(lam2), np.sqrt(lam2 / np.maximum(lam1, 1e-12))


def _shape_sums(p: _Points, m: _Moments, line_res: np.ndarray, width: np.ndarray):
    """(circle radius, circle residual, chord depth mean and largest, inscribed angles mean
    and std) of each segment, from one ``reduceat`` over the points.

    * Kasa circle fit on the centred points: [suu suv; suv svv] (uc, vc) = (bu, bv),
      r^2 = uc^2 + vc^2 + suu + svv; a straight segment (singular system or radius over
      RADIUS_CAP_M) gets the cap and its line-fit residual;
    * chord depth: distance of the points from the chord A-B (A, B the end points), positive
      on the laser's side;
    * inscribed angles APB of the interior points P."""
    fc, cid, first, last, px, py = p.fc, p.cid, p.first, p.last, p.px, p.py
    det = m.det
    ok = det > 1e-14
    sdet = np.where(ok, det, 1.0)
    uc = np.where(ok, (m.bu * m.svv - m.bv * m.suv) / sdet, 0.0)
    vc = np.where(ok, (m.bv * m.suu - m.bu * m.suv) / sdet, 0.0)
    radius = np.sqrt(uc * uc + vc * vc + m.tr)
    straight = ~ok | (radius > RADIUS_CAP_M)
    radius[straight] = RADIUS_CAP_M
    ax, ay = px[first], py[first]
    wx, wy = px[last] - ax, py[last] - ay
    wn = np.maximum(width, 1e-9)
    nx, ny = -wy / wn, wx / wn
    nx, ny = np.where(nx * ax + ny * ay > 0, (-nx, -ny), (nx, ny))  # normal towards the laser
    q = np.empty((4, px.shape[0]))
    e = np.hypot(m.u - uc[cid], m.v - vc[cid]) - radius[cid]
    np.multiply(e, e, out=q[0])
    pax, pay = ax[cid] - px, ay[cid] - py  # P -> A
    dep = np.multiply(nx[cid], -pax, out=q[1])
    dep -= ny[cid] * pay
    pbx, pby = pax + wx[cid], pay + wy[cid]  # P -> B
    ang = np.arctan2(pax * pby - pay * pbx, pax * pbx + pay * pby, out=q[2])
    np.abs(ang, out=ang)
    ang[first] = 0.0  # only the interior points
    ang[last] = 0.0
    np.multiply(ang, ang, out=q[3])
    sums = np.add.reduceat(q, first, axis=1)
    circ_res = np.sqrt(sums[0] / fc)
    circ_res = np.where(straight, line_res, np.minimum(circ_res, RADIUS_CAP_M))
    n_inner = np.maximum(fc - 2.0, 1.0)
    ia_mean = sums[2] / n_inner
    ia_std = np.sqrt(np.maximum(sums[3] / n_inner - ia_mean**2, 0.0))
    depth_max = np.maximum.reduceat(q[1], first)
    return radius, circ_res, sums[1] / fc, depth_max, ia_mean, ia_std


def _background_steps(r, outer, starts, ends) -> tuple[np.ndarray, np.ndarray]:
    """(smaller, larger) range step from each segment's end points to the beams just outside
    it (``outer``), capped at STEP_CAP_M (no return or outside the scan: far)."""
    steps = outer - r[np.array([starts, ends])]
    np.maximum(steps, -STEP_CAP_M, out=steps)
    np.minimum(steps, STEP_CAP_M, out=steps)
    return steps.min(axis=0), steps.max(axis=0)


def _context(cx, cy, width, fc, partner_shape: np.ndarray) -> list:
    """The context columns: the nearest other segment's distance, width and point count, the
    segments within 1 m and PARTNER_M, and ``partner_shape`` (rows: circle residual, line
    residual, radius, chord depth, larger step, range) of the nearest segment when it lies
    within PARTNER_M, its range as the difference to this segment's."""
    k = cx.shape[0]
    if k == 1:
        return [CONTEXT_CAP_M, 0.0, 0.0, 0.0, 0.0, *_NO_PARTNER[:, 0].tolist()]
    cz = cx + 1j * cy  # complex points: one subtraction, one hypot
    dd = np.abs(cz[:, None] - cz)
    dd.flat[:: k + 1] = np.inf  # not itself
    j = dd.argmin(axis=1)
    nd = dd[np.arange(k), j]
    near = nd < CONTEXT_CAP_M
    partner = nd < PARTNER_M
    cols = [
        np.minimum(nd, CONTEXT_CAP_M),
        np.where(near, width[j], 0.0),
        np.where(near, fc[j], 0.0),
        (dd < 1.0).sum(axis=1),
        (dd < PARTNER_M).sum(axis=1),
    ]
    shape = partner_shape[:, j]
    shape[5] -= partner_shape[5]
    return cols + list(np.where(partner, shape, _NO_PARTNER))


def _rows(cols: list, k: int) -> np.ndarray:
    """(k, len(cols)) float32, C-contiguous: one row per segment."""
    if k > 1:  # every column an array of k values: one conversion
        out = np.array(cols, dtype=np.float32)
    else:
        out = np.empty((len(cols), k), dtype=np.float32)
        for i, c in enumerate(cols):
            out[i] = c
    return np.ascontiguousarray(out.T)


def select_legs(
    x: np.ndarray,
    y: np.ndarray,
    score: np.ndarray,
    threshold: float,
    pair_threshold: float,
    pair_distance_m: float,
) -> list[tuple[int, ...]]:
    """Persons from scored legs: groups of indices into ``x``/``y``/``score``.

    Legs scoring at least ``min(threshold, pair_threshold)`` are paired (thesis 4.3.3); a pair
    is kept when both legs reach ``pair_threshold``, a lone leg (also one of a rejected pair)
    when it reaches ``threshold``.
    """
    cand = np.flatnonzero(score >= min(threshold, pair_threshold)).tolist()
    if not cand:
        return []
    s = score.tolist()
    groups = pair_legs([float(x[i]) for i in cand], [float(y[i]) for i in cand], pair_distance_m)
    out: list[tuple[int, ...]] = []
    for g in groups:
        legs = tuple(cand[i] for i in g)
        if len(legs) == 2 and min(s[legs[0]], s[legs[1]]) >= pair_threshold:
            out.append(legs)
        else:
            out.extend((i,) for i in legs if s[i] >= threshold)
    return out


class LegTracks:
    """Temporal confirmation of leg scores: short-lived leg tracks (beyond the seeds;
    in the spirit of leg_tracker's track confidence, our own code).

    Each track ``j`` has a position ``p_j`` in a registered frame, a velocity ``v_j`` and an
    evidence ``e_j`` in [0, 1]. For a scan ``Δt`` after the previous one, with segments at
    ``x_i`` (moved into the registered frame by the scan's ``pose``) scoring ``s_i``::

        a      = exp(−Δt / memory_s)                   share of the evidence kept
        p̂_j    = p_j + v_j Δt                          prediction (p_j when velocity is off)
        j(i)   : greedy nearest pairs |x_i − p̂_j| ≤ gate_m, each track and segment once
        out_i  = w s_i + (1 − w) e_j(i)                e_j(i) = 0 for a segment no track takes
        e_j    ← a e_j + (1 − a) s_i                   a running mean; a missed track: a e_j
        v_j    ← ½ v_j + ½ (x_i − p_j) / Δt,  p_j ← x_i
        new    : p = x_i, v = 0, e = (1 − a) s_i       as if its past scans had scored 0

    (The first scan of a stream has no Δt: ``a = 1``, its new tracks start at ``e = 0``.)

    So a leg seen over several scans keeps its score; a blob seen in one scan keeps ``w`` of
    it. Tracks whose evidence falls below 0.01 are dropped (at most ``max_tracks``, the
    strongest kept). A scan of another size, geometry or frame, a stamp going back or a pause
    longer than ``max_gap_s`` starts afresh; the caller resets when its registered frame
    restarts. Non-finite positions or scores neither match nor start tracks (their score is
    returned as it is).

    Parameters
    ----------
    memory_s: time constant of the evidence (s), > 0.
    weight: ``w``, share of the current scan's score in [0, 1] (1: no confirmation).
    gate_m: association radius (m).
    velocity: predict tracks at their velocity.
    max_gap_s: a longer pause between scans drops every track (s).
    """

    def __init__(
        self,
        memory_s: float,
        *,
        weight: float = 0.2,
        gate_m: float = 0.3,
        velocity: bool = True,
        max_gap_s: float = 0.5,
        max_tracks: int = 256,
    ) -> None:
        if not (memory_s > 0 and math.isfinite(memory_s)):
            raise ValueError("memory_s must be finite and > 0")
        if not 0.0 <= weight <= 1.0:
            raise ValueError("weight must be in [0, 1]")
        if not gate_m > 0 or not max_gap_s > 0 or max_tracks < 1:
            raise ValueError("gate_m and max_gap_s must be > 0, max_tracks >= 1")
        self.memory_s = float(memory_s)
        self.weight = float(weight)
        self.gate_m = float(gate_m)
        self.velocity = bool(velocity)
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.max_tracks = int(max_tracks)
        self.resets = 0
        """How many times the tracks were dropped for a new stream, a stamp going back or a
        pause (for tests)."""
        self._key: tuple | None = None
        self._clear()

    def _clear(self) -> None:
        self._stamp: int | None = None
        self._t = np.zeros((5, 0))  # rows: x, y, vx, vy, evidence

    def reset(self) -> None:
        """Drop every track (a new stream, or the registered frame restarted)."""
        self._key = None
        self._clear()

    @property
    def count(self) -> int:
        """How many tracks are kept."""
        return int(self._t.shape[1])

    def update(
        self,
        scan: LaserScan,
        x: np.ndarray,
        y: np.ndarray,
        score: np.ndarray,
        pose: np.ndarray | None = None,
    ) -> np.ndarray:
        """Confirmed scores of the segments at (``x``, ``y``) (laser frame) scoring ``score``;
        ``pose`` (x, y, θ) places the scan in the registered frame (None: the laser frame)."""
        score = np.asarray(score, dtype=np.float64)
        key = (scan.ranges.shape[0], float(scan.angle_min_rad), float(scan.angle_increment_rad))
        key += (scan.frame_id,)
        stamp = int(scan.stamp_ns)
        if key != self._key:
            if self._key is not None:
                self.resets += 1
            self._key = key
            self._clear()
        elif self._stamp is not None and not 0 <= stamp - self._stamp <= self.max_gap_ns:
            self.resets += 1
            self._clear()
        dt = 0.0 if self._stamp is None else (stamp - self._stamp) * 1e-9
        self._stamp = stamp
        a = math.exp(-dt / self.memory_s)
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if pose is not None:
            p0, p1, p2 = (float(v) for v in pose)
            if math.isfinite(p0) and math.isfinite(p1) and math.isfinite(p2):
                c, s_ = math.cos(p2), math.sin(p2)
                x, y = c * x - s_ * y + p0, s_ * x + c * y + p1
        finite = np.isfinite(score)
        usable = finite & np.isfinite(x) & np.isfinite(y)
        track = self._associate(x, y, usable, dt)  # the track each segment continues, or -1
        hit = np.flatnonzero(track >= 0)
        j = track[hit]
        t = self._t
        prior = np.zeros(score.shape[0])
        prior[hit] = t[4, j]
        out = self.weight * score + (1.0 - self.weight) * prior  # out_i = w s_i + (1 − w) e_j(i)
        if not finite.all():
            out[~finite] = score[~finite]
        # the tracks after this scan (in place: self._t is replaced below)
        e = t[4]
        e *= a  # a missed track: a e_j
        e[j] += (1.0 - a) * score[hit]  # e_j ← a e_j + (1 − a) s_i
        if dt > 0:
            t[2, j] = 0.5 * t[2, j] + 0.5 * (x[hit] - t[0, j]) / dt
            t[3, j] = 0.5 * t[3, j] + 0.5 * (y[hit] - t[1, j]) / dt
        t[0, j], t[1, j] = x[hit], y[hit]
        keep = e >= 0.01
        keep[j] = True
        new = np.flatnonzero(usable & (track < 0))
        if new.shape[0]:
            born = np.zeros((5, new.shape[0]))
            born[0], born[1] = x[new], y[new]
            born[4] = (1.0 - a) * score[new]
            t = np.concatenate([t[:, keep], born], axis=1)
        elif not keep.all():
            t = t[:, keep]
        e = t[4]
        np.minimum(np.maximum(e, 0.0, out=e), 1.0, out=e)
        if t.shape[1] > self.max_tracks:
            t = t[:, np.argsort(-e, kind="stable")[: self.max_tracks]]
        self._t = t
        return out

    def _associate(self, x: np.ndarray, y: np.ndarray, usable: np.ndarray, dt: float):
        """Greedy nearest pairs of segments (``usable`` ones) and predicted tracks within
        ``gate_m``, closest first, each once: the track index of each segment, -1 for none."""
        track = np.full(x.shape[0], -1, dtype=np.intp)
        t = self._t
        if t.shape[1] == 0:
            return track
        ok = np.flatnonzero(usable)
        if ok.shape[0] == 0:
            return track
        px, py = (t[0] + t[2] * dt, t[1] + t[3] * dt) if self.velocity else (t[0], t[1])
        d = np.hypot(x[ok, None] - px, y[ok, None] - py)
        si, tj = np.nonzero(d <= self.gate_m)
        if si.shape[0] == 0:
            return track
        sl, tl, okl = si.tolist(), tj.tolist(), ok.tolist()
        taken_s: set[int] = set()
        taken_t: set[int] = set()
        for f in np.argsort(d[si, tj], kind="stable").tolist():  # closest pairs first
            i, jj = sl[f], tl[f]
            if i not in taken_s and jj not in taken_t:
                taken_s.add(i)
                taken_t.add(jj)
                track[okl[i]] = jj
        return track


class RandomTreesLegDetector:
    """Random-trees classifier on segment features; legs paired into persons."""

    name = "learned"
    settings_type = LearnedSettings

    def __init__(self, settings: LearnedSettings | None = None, model=None) -> None:
        self.settings = s = settings or LearnedSettings()
        self._model = model
        self._path = Path(s.model_path) if s.model_path else None
        self.background: StaticBackground | None = None
        """The static-background model (stateful: scans are expected in order), or None."""
        if s.background_memory_s:
            self.background = StaticBackground(
                s.background_memory_s, hit_m=s.background_hit_m, ego_motion=s.background_ego_motion
            )
        self.tracks: LegTracks | None = None
        """The temporal confirmation stage (stateful), or None."""
        if s.track_memory_s:
            self.tracks = LegTracks(
                s.track_memory_s,
                weight=s.track_weight,
                gate_m=s.track_gate_m,
                velocity=s.track_velocity,
                max_gap_s=s.track_max_gap_s,
            )

    def reset(self) -> None:
        """Forget the scans seen so far (a new stream)."""
        if self.background is not None:
            self.background.reset()
        if self.tracks is not None:
            self.tracks.reset()

    def static_segments(
        self, scan: LaserScan, cx: np.ndarray, cy: np.ndarray, pose: LaserPose = None
    ) -> np.ndarray:
        """Register ``scan`` with the background model (at ``pose`` when given, else by
        matching); True for the segments (centroids ``cx``, ``cy``) that lie on static
        background. All False when the model is off."""
        if self.background is None:
            return np.zeros(cx.shape[0], dtype=bool)
        s = self.settings
        resets = self.background.resets
        hits, views = self.background.update(scan, cx, cy, pose)
        if self.background.resets != resets and self.tracks is not None:
            self.tracks.reset()  # the registered frame restarts
        return StaticBackground.static_mask(
            hits, views, s.background_static_fraction, s.background_min_views
        )

    def _pose(self, given: LaserPose) -> np.ndarray | LaserPose:
        """The last scan's pose in the background's registered frame; without the
        background, the ``given`` pose (None: the laser frame)."""
        return given if self.background is None else self.background.pose

    def check(self) -> None:
        """Load the model file now, so a missing or unreadable one is a ValueError naming it
        at start (and for ``followbot up --check``), not an error at the first scan."""
        path = self._path or default_model_path()
        try:
            model = self.model
        except FileNotFoundError as exc:
            raise ValueError(f"detector_settings.model_path: {exc}") from None
        except Exception as exc:  # cv2.error, a bad .gz (OSError, EOFError)
            raise ValueError(
                f"detector_settings.model_path: cannot load the learned leg model {path}: "
                f"{str(exc).strip()}"
            ) from None
        if not model.isTrained():
            raise ValueError(
                f"detector_settings.model_path: {path} holds no trained random-trees model"
            )

    @property
    def model(self):
        """The cv2.ml.RTrees model, loaded on first use (cv2 is imported lazily)."""
        if self._model is None:
            self._model = load_model(self._path or default_model_path())
        return self._model

    def leg_scores(self, features: np.ndarray) -> np.ndarray:
        """Vote share for "leg" of each row of ``features``."""
        if features.shape[0] == 0:
            return np.zeros(0)
        return vote_share(self.model, features)

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        s = self.settings
        seg = segments(
            scan, s.cluster_gap_m, s.min_points, s.max_width_m, s.max_range_m, s.dropout_beams
        )
        starts = seg.starts
        if starts.shape[0] == 0:
            z = np.zeros(0)
            if self.background is not None:  # the background and the tracks see every scan
                self.static_segments(scan, z, z, pose)
            if self.tracks is not None:
                self.tracks.update(scan, z, z, z, self._pose(pose))
            return candidates_message(scan, self.name, [])
        feats, cx, cy = features_and_centroids(seg)
        score = self.leg_scores(feats)
        if self.background is not None:
            score = score - s.background_penalty * self.static_segments(scan, cx, cy, pose)
        if self.tracks is not None:
            score = self.tracks.update(scan, cx, cy, score, self._pose(pose))
        if prediction is not None:
            px, py = float(prediction[0]), float(prediction[1])
            if math.isfinite(px) and math.isfinite(py):
                # thesis criterion 3: only segments near the tracked target
                score = np.where(np.hypot(cx - px, cy - py) < s.gate_m, score, -1.0)
        groups = select_legs(cx, cy, score, s.threshold, s.pair_threshold, s.pair_distance_m)
        if not groups:
            return candidates_message(scan, self.name, [])
        width = feats[:, 1].tolist()
        conf = score.tolist()
        first, last = _beam_spans(seg, scan.ranges.shape[0])
        out = []
        for g in groups:
            legs = [
                Leg(
                    x_m=float(cx[i]),
                    y_m=float(cy[i]),
                    first_beam=first[i],
                    last_beam=last[i],
                    width_m=width[i],
                )
                for i in g
            ]
            pattern = "two_legs" if len(g) == 2 else "one_leg"
            out.append(person(legs, pattern, min(1.0, max(0.0, *(conf[i] for i in g)))))
        return candidates_message(scan, self.name, out)


def _beam_spans(seg: Segments, n: int) -> tuple[list[int], list[int]]:
    """(first, last) beam of each segment for its Leg. A segment across the end of a full
    circle's scan (its first beam after its last) gets the part on the side of the scan's end
    where more of its beams lie (a Leg's span cannot wrap)."""
    first, last = seg.beam[seg.starts].tolist(), seg.beam[seg.ends].tolist()
    for i, (a, b) in enumerate(zip(first, last, strict=True)):
        if a > b:
            first[i], last[i] = (a, n - 1) if n - a > b + 1 else (0, b)
    return first, last


# --------------------------------------------------------------------------- model file


@functools.lru_cache(maxsize=4)
def load_model(path: Path):
    """Load an RTrees model (cached per path; the model is only read, never trained further);
    ``.gz`` files are decompressed to a temporary file first."""
    import gzip
    import tempfile

    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no learned leg model at {path}; train one with `python -m followbot.research.train`"
        )
    if path.suffix == ".gz":
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / path.stem
            plain.write_bytes(gzip.decompress(path.read_bytes()))
            return cv2.ml.RTrees_load(str(plain))
    return cv2.ml.RTrees_load(str(path))


def save_model(model, path: Path) -> None:
    import gzip
    import tempfile

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gz":
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / path.stem
            model.save(str(plain))
            # mtime=0: the same model gives the same bytes
            path.write_bytes(gzip.compress(plain.read_bytes(), mtime=0))
    else:
        model.save(str(path))


def _tree_count(model) -> int:
    """Number of trees (the saved term criteria do not survive loading): the votes of one
    sample summed over the classes."""
    cache = _TREES.get(id(model))
    if cache is not None and cache[0] is model:
        return cache[1]
    n_vars = int(model.getVarCount())
    votes = model.getVotes(np.zeros((1, n_vars), np.float32), 0)
    count = int(votes[1:].sum())
    _TREES[id(model)] = (model, count)
    return count


_TREES: dict[int, tuple[object, int]] = {}


def vote_share(model, features: np.ndarray) -> np.ndarray:
    """Share of the trees voting for class 1 ("leg").

    With class labels 0 and 1, ``DTREES_PREDICT_SUM`` sums the leaf values (the labels), i.e.
    counts the trees voting 1 — about twice as fast as ``getVotes``.
    """
    import cv2

    feats = np.ascontiguousarray(features, dtype=np.float32)
    _, out = model.predict(feats, flags=cv2.ml.DTREES_PREDICT_SUM)
    return out.ravel().astype(np.float64) / max(_tree_count(model), 1)
