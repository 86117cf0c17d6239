"""A 2-D laser scanner by vectorised ray casting against segments and circles.

Every beam i leaves the laser at o with unit direction d_i. Against a segment a -> b
(e = b - a, q = a - o) the hit is

    o + t d = a + u e   =>   t = (q x e) / (d x e),   u = (q x d) / (d x e),
    valid when d x e != 0, t > 0 and 0 <= u <= 1,

and against a circle (centre c, radius r, w = c - o), with beta = d . w,

    t = beta - sqrt(beta^2 - (|w|^2 - r^2)),   valid when the root is real and t > 0,

where ``x`` is the 2-D cross product. All beams x all shapes are one (N, M) array operation; the
range of a beam is the smallest valid t, and the index of the shape hit is kept so the truth can
say which person a beam saw. Shapes beyond the maximum range are culled first.

The measurement model then adds Gaussian range noise (thesis 5.1, SICK LMS200: 15 mm), drops
beams (NaN: no measurement) and inserts spurious short returns (uniform between the minimum
range and the true range). A beam that hits nothing within range reads +inf (REP-117).
The ``measured`` model (LaserSpec ``model: measured``, parameters in ``MeasuredLaserSpec``,
values and their sources in docs/realism.md) reproduces what real scanners do instead:

* range noise with std ``noise_at_zero_m + noise_per_m * r``, ranges rounded to
  ``range_resolution_m``;
* leg dropouts correlated in time and per person: each leg is a two-state Markov chain
  (in a dropout a share ``leg_dropout_prob`` of scans, ``leg_dropout_scans`` long on
  average), and a person wears dark trousers (drawn once) with ``dark_trousers_prob``; a beam
  on a leg in a dropout or on dark trousers returns only with ``leg_dropout_return_prob`` or
  ``dark_return_prob``, so one leg can vanish while the other is seen;
* at a foreground edge (neighbouring true ranges ``edge_min_jump_m`` apart), the background
  beam next to the edge is a mixed pixel (``mixed_pixel_prob``: a range drawn uniformly
  between the edge and the background) or reads no return (``edge_invalid_prob``);
* scattered invalid beams (``invalid_prob``) and duplicated beams (``duplicate_prob``: a
  beam repeats its predecessor's reading).

No return reads NaN, nothing within ``range_max_m`` reads +inf.

The scan is taken at one instant: the beams of a real scanner are spread over the scan time,
which at 0.75 m/s and 13 ms per sweep moves the robot 10 mm -- below the range noise.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from followbot.schemas import LaserScan

from .scenario import LaserSpec

__all__ = ["LaserModel", "cast_rays"]


_TWO_PI = 2.0 * math.pi


def _beam_spans(
    lo_rad: np.ndarray, width_rad: np.ndarray, a0_rad: float, inc_rad: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(beam, shape) pairs for shapes covering world angles [lo, lo + width].

    Beam i points at a0 + i inc. An interval is put into [a0, a0 + 2 pi) and also tried one
    turn earlier, so intervals that wrap round the back of the scanner are found.
    """
    lo = a0_rad + np.mod(lo_rad - a0_rad, _TWO_PI) - 1e-9
    hi = lo + width_rad + 2e-9
    shape = np.arange(lo.shape[0])
    first = np.concatenate(
        [np.ceil((lo - a0_rad) / inc_rad), np.ceil((lo - _TWO_PI - a0_rad) / inc_rad)]
    )
    last = np.concatenate(
        [np.floor((hi - a0_rad) / inc_rad), np.floor((hi - _TWO_PI - a0_rad) / inc_rad)]
    )
    first = np.maximum(first, 0).astype(np.int64)
    last = np.minimum(last, n - 1).astype(np.int64)
    count = np.maximum(last - first + 1, 0)
    shape = np.concatenate([shape, shape])
    total = int(count.sum())
    owner = np.repeat(shape, count)
    starts = np.cumsum(count) - count
    beam = np.arange(total) - np.repeat(starts - first, count)
    return beam, owner, count


def cast_rays(
    origin: tuple[float, float],
    a0_rad: float,
    inc_rad: float,
    n_beams: int,
    segments: np.ndarray,
    circles: np.ndarray,
    max_range_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact first hit of every ray of a uniform fan.

    Only (beam, shape) pairs whose angular span overlaps are intersected: each circle covers
    bearing +- asin(r / |w|), each segment the arc between its end points' bearings. A scene of
    90 circles and 44 segments then needs ~2 000 intersections instead of 720 x 134.

    Parameters
    ----------
    origin: (x, y) of the sensor.
    a0_rad, inc_rad, n_beams: beam i points at world angle ``a0 + i * inc``.
    segments: (M, 4) rows [x0, y0, x1, y1].
    circles: (K, 3) rows [x, y, r] (a circle round the sensor is ignored).
    max_range_m: rays hit nothing beyond this.

    Returns
    -------
    ranges: (N,) float64, ``inf`` where nothing is hit within ``max_range_m``.
    hit: (N,) int64 index of the shape hit: 0..M-1 a segment, M..M+K-1 a circle, -1 none.
    """
    fan = _Fan(origin, a0_rad, inc_rad, n_beams, max_range_m)
    hits = [
        _segment_hits(fan, segments),
        _circle_hits(fan, circles, id_offset=segments.shape[0]),
    ]
    return _nearest_per_beam(n_beams, max_range_m, [h for h in hits if h is not None])


class _Fan(msgspec.Struct, frozen=True):
    """A uniform fan of rays: beam i from ``origin`` at world angle ``a0 + i * inc``."""

    origin: tuple[float, float]
    a0_rad: float
    inc_rad: float
    n_beams: int
    max_range_m: float

    def directions(self, beam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        angles = self.a0_rad + self.inc_rad * beam
        return np.cos(angles), np.sin(angles)


_Hits = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(beam, distance along the beam, shape index) of every intersection found."""


def _segment_hits(fan: _Fan, segments: np.ndarray) -> _Hits | None:
    """Intersections of the fan with the segments [x0, y0, x1, y1] (shape index = row)."""
    if not segments.shape[0]:
        return None
    ox, oy = fan.origin
    ax = segments[:, 0] - ox
    ay = segments[:, 1] - oy
    bx = segments[:, 2] - ox
    by = segments[:, 3] - oy
    ex, ey = bx - ax, by - ay
    # cull segments wholly out of range: distance from o to the segment > max range
    ee = ex * ex + ey * ey
    lam = np.clip(-(ax * ex + ay * ey) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
    keep = np.flatnonzero(np.hypot(ax + lam * ex, ay + lam * ey) <= fan.max_range_m)
    if not keep.size:
        return None
    ax, ay, ex, ey = ax[keep], ay[keep], ex[keep], ey[keep]
    phi0 = np.arctan2(ay, ax)
    dphi = np.arctan2(by[keep], bx[keep]) - phi0
    dphi = (dphi + math.pi) % _TWO_PI - math.pi  # the arc the segment subtends
    beam, own, _ = _beam_spans(
        phi0 + np.minimum(dphi, 0.0), np.abs(dphi), fan.a0_rad, fan.inc_rad, fan.n_beams
    )
    dx, dy = fan.directions(beam)
    qx, qy, sx, sy = ax[own], ay[own], ex[own], ey[own]
    denom = dx * sy - dy * sx  # d x e
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / denom
        t = (qx * sy - qy * sx) * inv  # (q x e) / (d x e)
        u = (qx * dy - qy * dx) * inv  # (q x d) / (d x e)
    ok = (t > 0.0) & (u >= -1e-9) & (u <= 1.0 + 1e-9)
    return beam[ok], t[ok], keep[own[ok]]


def _circle_hits(fan: _Fan, circles: np.ndarray, id_offset: int) -> _Hits | None:
    """Intersections of the fan with the circles [x, y, r] (shape index = id_offset + row)."""
    if not circles.shape[0]:
        return None
    ox, oy = fan.origin
    wx = circles[:, 0] - ox
    wy = circles[:, 1] - oy
    r = circles[:, 2]
    dist = np.hypot(wx, wy)
    keep = np.flatnonzero((dist > r) & (dist - r <= fan.max_range_m))
    if not keep.size:
        return None
    wx, wy, r, dist = wx[keep], wy[keep], r[keep], dist[keep]
    half = np.arcsin(r / dist)
    beam, own, _ = _beam_spans(
        np.arctan2(wy, wx) - half, 2 * half, fan.a0_rad, fan.inc_rad, fan.n_beams
    )
    dx, dy = fan.directions(beam)
    beta = dx * wx[own] + dy * wy[own]  # d . w
    disc = beta * beta - (dist[own] ** 2 - r[own] ** 2)
    ok = disc >= 0.0
    t = beta[ok] - np.sqrt(disc[ok])
    ok2 = t > 0.0
    return beam[ok][ok2], t[ok2], id_offset + keep[own[ok][ok2]]


def _nearest_per_beam(
    n_beams: int, max_range_m: float, hits: list[_Hits]
) -> tuple[np.ndarray, np.ndarray]:
    """(ranges, shape index) of each beam's nearest intersection within range (inf, -1: none)."""
    best = np.full(n_beams, np.inf)
    hit = np.full(n_beams, -1, dtype=np.int64)
    if not hits:
        return best, hit
    beam = np.concatenate([h[0] for h in hits])
    t = np.concatenate([h[1] for h in hits])
    ident = np.concatenate([h[2] for h in hits])
    inside = t <= max_range_m
    beam, t, ident = beam[inside], t[inside], ident[inside]
    # nearest hit per beam: unbuffered minimum, then the shape that attains it
    np.minimum.at(best, beam, t)
    win = t == best[beam]
    hit[beam[win]] = ident[win]
    return best, hit


class LaserModel:
    """Beam layout and measurement noise of one scanner (settings from :class:`LaserSpec`)."""

    def __init__(self, spec: LaserSpec) -> None:
        self.spec = spec
        fov = math.radians(spec.fov_deg)
        inc = math.radians(spec.resolution_deg)
        if spec.fov_deg >= 360.0 - 1e-9:
            n = round(2 * math.pi / inc)  # full turn: the last beam would repeat the first
            self.angle_min_rad = -math.pi
        else:
            n = round(fov / inc) + 1  # thesis 5.1: 100 deg at 0.5 deg -> 201 beams
            self.angle_min_rad = -fov / 2
        self.angle_increment_rad = inc
        self.n_beams = int(n)
        self.angles_rad = self.angle_min_rad + inc * np.arange(self.n_beams, dtype=np.float64)
        self.period_s = 1.0 / spec.rate_hz
        self._dropped: np.ndarray | None = None  # measured model: legs in a dropout
        self._dark = np.zeros(0, dtype=bool)  # measured model: legs in dark trousers

    def cast(
        self,
        pose: tuple[float, float, float],
        segments: np.ndarray,
        circles: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free ranges and hit indices from the robot pose (x, y, yaw) in the world."""
        x, y, yaw = pose
        mx, my = self.spec.mount_x_m, self.spec.mount_y_m  # the mount, in the base frame
        ox = x + mx * math.cos(yaw) - my * math.sin(yaw)
        oy = y + mx * math.sin(yaw) + my * math.cos(yaw)
        return cast_rays(
            (ox, oy),
            self.angle_min_rad + yaw + math.radians(self.spec.mount_yaw_deg),
            self.angle_increment_rad,
            self.n_beams,
            segments,
            circles,
            self.spec.range_max_m,
        )

    def corrupt(
        self,
        true_ranges: np.ndarray,
        rng: np.random.Generator,
        *,
        hit: np.ndarray | None = None,
        first_leg: int = 0,
        n_legs: int = 0,
    ) -> np.ndarray:
        """Apply the measurement model; returns float32 ranges for the wire.

        ``hit`` (from :meth:`cast`) with ``first_leg`` and ``n_legs`` says which beams hit a
        leg: shape indices ``first_leg + 2 k + j`` are leg j of person k (the measured model's
        leg dropouts; the ideal model ignores them). The same number of random draws is made
        whatever the scene, so the noise stream does not depend on what the beams hit.
        """
        if self.spec.model == "measured":
            return self._corrupt_measured(true_ranges, rng, hit, first_leg, n_legs)
        s = self.spec
        n = true_ranges.shape[0]
        noise = rng.normal(0.0, 1.0, n) * s.range_noise_m
        drop = rng.random(n) < s.dropout_prob
        spur = rng.random(n) < s.spurious_prob
        spur_frac = rng.random(n)
        r = true_ranges + noise
        finite = np.isfinite(true_ranges)
        short_of = np.where(finite, true_ranges, s.range_max_m)
        r = np.where(spur, s.range_min_m + spur_frac * (short_of - s.range_min_m), r)
        r = np.where(finite | spur, r, np.inf)
        r = np.where(r > s.range_max_m, np.inf, r)
        r = np.where(r < s.range_min_m, s.range_min_m, r)
        r = np.where(drop, np.nan, r)
        return r.astype(np.float32)

    def _leg_returns(self, rng: np.random.Generator, n_legs: int) -> np.ndarray:
        """Per leg, the probability that a beam on it returns this scan (module doc)."""
        m = self.spec.measured
        if self._dropped is None or self._dropped.shape[0] != n_legs:
            # first scan: each leg starts in its chain's stationary state; dark trousers are
            # drawn per person, the same for both legs
            self._dropped = rng.random(n_legs) < m.leg_dropout_prob
            dark = rng.random((n_legs + 1) // 2) < m.dark_trousers_prob
            self._dark = np.repeat(dark, 2)[:n_legs]
        leave = 1.0 / m.leg_dropout_scans
        p = m.leg_dropout_prob
        enter = min(1.0, p * leave / (1.0 - p)) if p < 1.0 else 1.0
        u = rng.random(n_legs)
        self._dropped = np.where(self._dropped, u >= leave, u < enter)
        ret = np.where(self._dark, m.dark_return_prob, 1.0)
        return np.where(self._dropped, np.minimum(ret, m.leg_dropout_return_prob), ret)

    def _corrupt_measured(
        self,
        true: np.ndarray,
        rng: np.random.Generator,
        hit: np.ndarray | None,
        first_leg: int,
        n_legs: int,
    ) -> np.ndarray:
        s, m = self.spec, self.spec.measured
        n = true.shape[0]
        leg_ret = self._leg_returns(rng, n_legs)
        gauss = rng.normal(0.0, 1.0, n)
        u_edge, u_mix, u_inv, u_dup, u_leg = rng.random((5, n))
        finite = np.isfinite(true)
        r = true.copy()
        # mixed pixels: a background beam beside a foreground edge (either side)
        far = np.where(finite, true, np.inf)
        for bg, fg in ((slice(1, None), slice(None, -1)), (slice(None, -1), slice(1, None))):
            with np.errstate(invalid="ignore"):  # inf - inf: both beyond range, no edge
                edge = far[bg] - far[fg] > m.edge_min_jump_m
            sub = r[bg]
            mixed = edge & (u_edge[bg] < m.mixed_pixel_prob) & np.isfinite(far[bg])
            gone = edge & (u_edge[bg] >= m.mixed_pixel_prob)
            gone &= u_edge[bg] < m.mixed_pixel_prob + m.edge_invalid_prob
            with np.errstate(invalid="ignore"):
                lerp = far[fg] + u_mix[bg] * (far[bg] - far[fg])
            sub[:] = np.where(mixed, lerp, np.where(gone, np.nan, sub))
        r = r + gauss * (m.noise_at_zero_m + m.noise_per_m * np.where(np.isfinite(r), r, 0.0))
        invalid = u_inv < m.invalid_prob
        if hit is not None and n_legs:
            leg = hit - first_leg
            on_leg = (leg >= 0) & (leg < n_legs)
            p = np.where(on_leg, leg_ret[np.clip(leg, 0, n_legs - 1)], 1.0)
            invalid |= u_leg >= p
        r = np.where(invalid, np.nan, r)
        if m.range_resolution_m > 0:
            r = np.round(r / m.range_resolution_m) * m.range_resolution_m
        # duplicated beams: a beam repeats the reading of the beam before it (one beam back,
        # so a duplicate never carries a reading across several beams)
        dup = np.flatnonzero(u_dup[1:] < m.duplicate_prob) + 1
        r[dup] = r[dup - 1].copy()
        with np.errstate(invalid="ignore"):
            r = np.where(r > s.range_max_m, np.inf, r)
            r = np.where(r < s.range_min_m, np.nan, r)
        return r.astype(np.float32)

    def to_message(self, ranges: np.ndarray, *, stamp_ns: int, seq: int) -> LaserScan:
        return LaserScan.from_ranges(
            ranges,
            stamp_ns=stamp_ns,
            angle_min_rad=self.angle_min_rad,
            angle_increment_rad=self.angle_increment_rad,
            range_min_m=self.spec.range_min_m,
            range_max_m=self.spec.range_max_m,
            frame_id="base_laser",
            seq=seq,
            scan_time_s=self.period_s,
        )
