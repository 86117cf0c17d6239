"""Scan geometry every stage reads the same way: which beams hold a return, and where each
beam points (docs/messages.md, LaserScan)."""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["beam_geometry", "valid_mask"]


def valid_mask(ranges_m: np.ndarray, range_min_m: float, range_max_m: float) -> np.ndarray:
    """True where a beam has a return: > 0 and within [range_min_m, range_max_m].

    NaN compares False with everything (no warning for comparisons), so it falls out of the
    bounds test by itself, and so do +-inf through ``range_max_m``.
    """
    lo = float(range_min_m)
    above = ranges_m >= lo if lo > 0 else ranges_m > 0.0
    return above & (ranges_m <= range_max_m)


@functools.lru_cache(maxsize=32)
def beam_geometry(
    angle_min_rad: float, angle_increment_rad: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bearings, cosines and sines of every beam, each padded with one trailing 0.

    Read-only and cached per scan geometry. The padding lets ``reduceat`` run over
    interleaved ``[start, end + 1]`` bounds (see :meth:`Clusters.bounds`).
    """
    angles = np.zeros(n + 1)
    angles[:n] = angle_min_rad + angle_increment_rad * np.arange(n, dtype=np.float64)
    cos = np.cos(angles)
    sin = np.sin(angles)
    cos[n] = sin[n] = 0.0
    for a in (angles, cos, sin):
        a.flags.writeable = False
    return angles, cos, sin
