"""One scan made ready for detection (DESIGN.md "Leg candidates").

* beam validity: NaN, +-inf, 0, ``< range_min_m`` and ``> range_max_m`` are "no return";
* polar -> cartesian in the scan's frame (REP-103: x forward, y left, angles counter-clockwise);
  the cos/sin tables are cached per scan geometry (a scanner's geometry never changes), and
  cartesian points are computed only for the beams a detector asks about;
* the thesis's range clip (4.3.1), the reach a detector reports, and the horizon (the nearest
  return per bearing bin) the tracker uses to tell hidden from gone.
"""

from __future__ import annotations

import functools
import math

import msgspec
import numpy as np

from followbot.schemas import Array, Horizon, LaserScan
from followbot.services.common.geometry import wrap_angle
from followbot.services.common.scan import beam_geometry, valid_mask

#: Range given to "no return" beams inside a detector: far below any real range, so a jump to
#: or from such a beam always splits clusters, and finite, so arithmetic on it stays finite.
NO_RETURN = -1.0e6


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
