"""Camera stage and hybrid filter benchmark, seed 001 (``make bench``).

Median over repeats, on a simulator frame (320x240, two people, one in the learnt colour):
colour classification of the frame, its regions, the whole camera stage (both), and one step of
the hybrid filter with 150 particles (seed 5.1) and with 1 000, with the robot's motion between
frames (the prediction through the floor) and two regions. Ratios against the stage's budget
of one 10 Hz camera frame (100 ms).

    python -m followbot.services.camera_blobs.bench
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np

from followbot.services.runtime.ground_plane import GroundCamera

from .core import classify, learn_colour, regions

__all__ = ["main"]


def _median_us(fn, repeats: int = 200) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def _frame() -> np.ndarray:
    """A 320x240 grey room with two painted people, one in red trousers (the learnt colour)."""
    import cv2

    rng = np.random.default_rng(0)
    img = np.full((240, 320, 3), 120, np.uint8)
    img[:100] = (200, 200, 205)
    cv2.rectangle(img, (100, 90), (140, 220), (40, 40, 200), -1)  # red trousers (BGR)
    cv2.rectangle(img, (95, 30), (145, 90), (220, 220, 220), -1)
    cv2.rectangle(img, (220, 100), (245, 190), (60, 50, 40), -1)
    noise = rng.normal(0, 3, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def main() -> int:
    from followbot.services.tracker.estimators.hybrid import HybridFilter, HybridSettings

    img = _frame()
    model = learn_colour(img, (110, 120, 20, 60))
    mask = classify(img, model)
    boxes = regions(mask)
    stage_us = _median_us(lambda: regions(classify(img, model)))
    print("camera stage (seed 001 3.1-3.2), 320x240 frame, median per frame:")
    print(f"  classify H,S       {_median_us(lambda: classify(img, model)):8.0f} us")
    print(f"  regions            {_median_us(lambda: regions(mask)):8.0f} us")
    print(f"  whole stage        {stage_us:8.0f} us   ({stage_us / 1e5:.2%} of a 10 Hz frame)")
    cam = GroundCamera(height_m=0.4)
    c, s = math.cos(0.02), math.sin(0.02)
    rot, trans = np.array([[c, -s], [s, c]]), np.array([-0.05, 0.0])
    two = np.vstack([boxes[:1], [[232.0, 145.0, 25.0, 90.0]]])
    print("hybrid filter (seed 001 3.3, 4), one step with odometry and two regions:")
    per = {}
    for n in (150, 1000):
        rng = np.random.default_rng(1)
        f = HybridFilter(boxes[0], HybridSettings(particles=n, camera=cam), rng)
        per[n] = _median_us(lambda f=f: f.step(two, 0.1, rot, trans))
        print(f"  {n:5d} particles    {per[n]:8.0f} us   ({per[n] / 1e5:.2%} of a 10 Hz frame)")
    print(f"  1000 / 150 particles: {per[1000] / per[150]:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
