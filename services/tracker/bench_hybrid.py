"""Hybrid filter benchmark, seed 001 (``make bench``).

Median over repeats of one step of the hybrid filter (services/tracker/estimators/hybrid.py)
with 150 particles (seed 5.1) and with 1 000, with the robot's motion between frames (the
prediction through the floor) and two regions of a 320x240 image, against the budget of one
10 Hz camera frame (100 ms), and the ratio of the two.

    python -m followbot.services.tracker.bench_hybrid
"""

from __future__ import annotations

import math

import numpy as np

from followbot.services.runtime.ground_plane import GroundCamera
from followbot.services.runtime.stats import median_us

from .estimators.hybrid import HybridFilter, HybridSettings

__all__ = ["main"]


def main() -> int:
    cam = GroundCamera(height_m=0.4)
    c, s = math.cos(0.02), math.sin(0.02)
    rot, trans = np.array([[c, -s], [s, c]]), np.array([-0.05, 0.0])
    # the target's trousers and a second region of another size, pixels [x, y, w, h]
    two = np.array([[120.0, 155.0, 41.0, 131.0], [232.0, 145.0, 25.0, 90.0]])
    print("hybrid filter (seed 001 3.3, 4), one step with odometry and two regions:")
    per = {}
    for n in (150, 1000):
        rng = np.random.default_rng(1)
        f = HybridFilter(two[0], HybridSettings(particles=n, camera=cam), rng)
        per[n] = median_us(lambda f=f: f.step(two, 0.1, rot, trans))
        print(f"  {n:5d} particles    {per[n]:8.0f} us   ({per[n] / 1e5:.2%} of a 10 Hz frame)")
    print(f"  1000 / 150 particles: {per[1000] / per[150]:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
