"""Camera stage benchmark, seed 001 (``make bench``).

Median over repeats, on a simulator-like frame (320x240, two people, one in the learnt
colour): colour classification of the frame, its regions, and the whole camera stage (both),
against the stage's budget of one 10 Hz camera frame (100 ms). The hybrid filter's cost is in
services/tracker/bench_hybrid.py.

    python -m followbot.services.camera_blobs.bench
"""

from __future__ import annotations

import numpy as np

from followbot.services.runtime.stats import median_us

from .core import classify, learn_colour, regions

__all__ = ["main"]


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
    img = _frame()
    model = learn_colour(img, (110, 120, 20, 60))
    mask = classify(img, model)
    stage_us = median_us(lambda: regions(classify(img, model)))
    print("camera stage (seed 001 3.1-3.2), 320x240 frame, median per frame:")
    print(f"  classify H,S       {median_us(lambda: classify(img, model)):8.0f} us")
    print(f"  regions            {median_us(lambda: regions(mask)):8.0f} us")
    print(f"  whole stage        {stage_us:8.0f} us   ({stage_us / 1e5:.2%} of a 10 Hz frame)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
