"""A synthetic room for the laser odometry tests: scans of it from any laser pose."""

from __future__ import annotations

import math

import numpy as np

from followbot.schemas import LaserScan
from followbot.services.laser_legs.scene import make_scan

PERIOD_NS = 100_000_000  # 10 Hz
#: A room with a corridor off it, a pillar and a cupboard: enough structure for every axis.
ROOM = [
    (-3.0, -3.0, 8.0, -3.0), (8.0, -3.0, 8.0, 1.0), (8.0, 1.0, 12.0, 1.0), (12.0, 1.0, 12.0, 3.0),
    (12.0, 3.0, -3.0, 3.0), (-3.0, 3.0, -3.0, -3.0),
    (2.0, 2.2, 3.5, 2.2), (3.5, 2.2, 3.5, 3.0),  # a cupboard against the left wall
]  # fmt: skip
PILLARS = [(4.0, -1.5, 0.15), (1.0, 1.0, 0.1)]


def to_laser(pose, x, y):
    """World point (x, y) in the frame of the laser at world ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = x - pose[0], y - pose[1]
    return c * dx + s * dy, -s * dx + c * dy


def room_scan(pose, k: int, noise_m: float = 0.01, **kw) -> LaserScan:
    """A 270° scan, 0.5° beams, of the room from a laser at world ``pose``; stamp k * 100 ms."""
    circles = [(*to_laser(pose, cx, cy), r) for cx, cy, r in PILLARS]
    walls = [(*to_laser(pose, a, b), *to_laser(pose, c, d)) for a, b, c, d in ROOM]
    kw.setdefault("fov_rad", math.radians(270))
    return make_scan(circles, walls, stamp_ns=k * PERIOD_NS, noise_m=noise_m,
                     rng=np.random.default_rng(k), range_max_m=20.0, **kw)  # fmt: skip
