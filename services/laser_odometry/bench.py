"""laser_odometry benchmark (``make bench``): the cost of one 720-beam scan.

A 360° scanner with 0.5° beams (legs360's) in a 10 x 6 m room with two pillars, driving at
0.5 m/s and turning at 15°/s, 10 Hz, 1 cm range noise: median time of
:meth:`ScanOdometry.update <followbot.services.laser_odometry.core.ScanOdometry.update>` over
the scans of the drive (matched against the keyframe), and of a still laser (every scan
against the first), against the budget of a 40 Hz scanner (25 ms).

    python -m followbot.services.laser_odometry.bench
"""

from __future__ import annotations

import math
import time

import numpy as np

from followbot.schemas import LaserScan

from .core import ScanOdometry
from .settings import LaserOdometrySettings

__all__ = ["main"]

BEAMS = 720
_WALLS = np.array([(-4, -3, 6, -3), (6, -3, 6, 3), (6, 3, -4, 3), (-4, 3, -4, -3)], float)
_PILLARS = np.array([(2.0, -1.0, 0.15), (-1.0, 1.5, 0.1)])


def _scan(pose, k: int, rng) -> LaserScan:
    """The room seen from the laser at world ``pose``: nearest wall or pillar per beam."""
    x, y, th = pose
    a = th - math.pi + np.arange(BEAMS) * (2 * math.pi / BEAMS)
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    x0, y0, x1, y1 = (_WALLS[:, i] - o for i, o in enumerate((x, y, x, y)))
    ex, ey = x1 - x0, y1 - y0
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (x0 * ey - y0 * ex) / den
        u = (x0 * dy - y0 * dx) / den
    t = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf).min(axis=1)
    for cx, cy, r in _PILLARS:
        dc = dx[:, 0] * (cx - x) + dy[:, 0] * (cy - y)
        disc = dc * dc - ((cx - x) ** 2 + (cy - y) ** 2) + r * r
        hit = np.where(disc >= 0, dc - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        t = np.minimum(t, np.where(hit > 0, hit, np.inf))
    ranges = (t + rng.normal(0.0, 0.01, BEAMS)).astype(np.float32)
    return LaserScan.from_ranges(
        ranges, stamp_ns=k * 100_000_000, frame_id="laser", angle_min_rad=-math.pi,
        angle_increment_rad=2 * math.pi / BEAMS, range_min_m=0.05, range_max_m=20.0,
    )  # fmt: skip


def _per_scan_us(scans: list[LaserScan]) -> float:
    odo = ScanOdometry(LaserOdometrySettings())
    times = []
    for s in scans:
        t0 = time.perf_counter_ns()
        odo.update(s)
        times.append(time.perf_counter_ns() - t0)
    return float(np.median(times[1:])) / 1e3  # the first scan only becomes the keyframe


def main() -> int:
    rng = np.random.default_rng(0)
    # 0.5 m/s along the room while turning at 15°/s (a holonomic base's drive: every axis moves)
    drive = [_scan((-2.0 + 0.05 * k, 0.0, math.radians(1.5) * k), k, rng) for k in range(60)]
    still = [_scan((0.0, 0.0, 0.2), k, rng) for k in range(200)]
    moving_us = _per_scan_us(drive)
    still_us = _per_scan_us(still)
    print(f"laser_odometry, {BEAMS}-beam scan (0.5 deg), median per scan:")
    print(f"  moving, 0.5 m/s 15 deg/s  {moving_us:8.0f} us   ({moving_us / 250:.1f} % of 25 ms)")
    print(f"  still                    {still_us:8.0f} us   ({still_us / 250:.1f} % of 25 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
