"""Synthetic laser scans by ray casting circles (legs, posts) and segments (walls).

Used by the tests, the benchmark and the Table 5.1 arc-walk experiment. Everything is in the
laser frame (REP-103), metres and radians.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from followbot.schemas import LaserScan

__all__ = ["cast", "make_scan", "person_legs"]

Circle = tuple[float, float, float]
"""(cx, cy, radius)"""
Segment = tuple[float, float, float, float]
"""(x0, y0, x1, y1)"""


def cast(
    angles: np.ndarray,
    circles: Sequence[Circle] = (),
    segments: Sequence[Segment] = (),
) -> np.ndarray:
    """Range of the first hit along every beam from the origin; inf where nothing is hit."""
    dx, dy = np.cos(angles), np.sin(angles)
    best = np.full(angles.shape, np.inf)
    for cx, cy, rad in circles:
        # |t d - c|^2 = R^2  ->  t = d.c - sqrt((d.c)^2 - |c|^2 + R^2)
        dc = dx * cx + dy * cy
        disc = dc * dc - (cx * cx + cy * cy) + rad * rad
        hit = disc >= 0
        t = np.where(hit, dc - np.sqrt(np.where(hit, disc, 0.0)), np.inf)
        t = np.where(t > 0, t, np.inf)
        np.minimum(best, t, out=best)
    for x0, y0, x1, y1 in segments:
        ex, ey = x1 - x0, y1 - y0
        den = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (x0 * ey - y0 * ex) / den
            u = (x0 * dy - y0 * dx) / den
        ok = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        np.minimum(best, np.where(ok, t, np.inf), out=best)
    return best


def person_legs(
    x_m: float, y_m: float, separation_m: float = 0.3, leg_radius_m: float = 0.06
) -> list[Circle]:
    """Two legs of a person at (x, y), side by side as seen from the laser."""
    rng = math.hypot(x_m, y_m) or 1.0
    # perpendicular to the line of sight
    px, py = -y_m / rng, x_m / rng
    h = separation_m / 2
    return [
        (x_m + h * px, y_m + h * py, leg_radius_m),
        (x_m - h * px, y_m - h * py, leg_radius_m),
    ]


def make_scan(
    circles: Sequence[Circle] = (),
    segments: Sequence[Segment] = (),
    *,
    fov_rad: float = math.radians(180.0),
    increment_rad: float = math.radians(0.5),
    angle_min_rad: float | None = None,
    range_min_m: float = 0.02,
    range_max_m: float = 30.0,
    noise_m: float = 0.0,
    rng: np.random.Generator | None = None,
    stamp_ns: int = 0,
    dtype: type = np.float32,
) -> LaserScan:
    """A scan of the scene; beams that hit nothing read +inf ("no return")."""
    n = round(fov_rad / abs(increment_rad)) + 1
    a0 = -fov_rad / 2 if angle_min_rad is None else angle_min_rad
    angles = a0 + increment_rad * np.arange(n)
    r = cast(angles, circles, segments)
    if noise_m > 0:
        rng = rng or np.random.default_rng(0)
        r = r + rng.normal(0.0, noise_m, r.shape)
    return LaserScan.from_ranges(
        r.astype(dtype),
        stamp_ns=stamp_ns,
        angle_min_rad=a0,
        angle_increment_rad=increment_rad,
        range_min_m=range_min_m,
        range_max_m=range_max_m,
    )
