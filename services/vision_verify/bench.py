"""Timing of the histogram verifier (printed, never asserted): ``python -m
followbot.services.vision_verify.bench``.

* both histograms of one 100 x 200 patch (DESIGN.md target <= 0.3 ms);
* ten candidates of one 320 x 240 frame judged against a model (target <= 3 ms), including the
  per-frame colour conversion and gradients shared by the rectangles.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from .core import Camera, ImageFeatures, Model, colour_histogram, edge_histogram, judge
from .verifiers.histogram import HistogramVerifier


def _median_ms(fn, n: int) -> tuple[float, float]:
    fn()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), float(np.percentile(times, 99))


def main() -> int:
    cv2.setNumThreads(1)  # one core, as the target says
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), (7, 7), 2)
    patch = np.ascontiguousarray(texture[20:220, 100:200])  # 100 wide x 200 high
    p50, p99 = _median_ms(lambda: (colour_histogram(patch), edge_histogram(patch)), 2000)
    print(f"both histograms, 100x200 patch: p50 {p50:.3f} ms, p99 {p99:.3f} ms (target 0.3)")
    v = HistogramVerifier()
    frame = ImageFeatures(texture)
    model = Model(
        model_id=1,
        verifier="histogram",
        x_m=2.0,
        y_m=0.0,
        depth_m=2.0,
        rect_w_px=100,
        rect_h_px=200,
        image_width=320,
        image_height=240,
        features=frame.histograms((110, 20, 210, 220)),
    )
    xy = np.column_stack([np.full(10, 2.0), np.linspace(-0.8, 0.8, 10)])
    cam = Camera()
    p50, p99 = _median_ms(lambda: judge(v, ImageFeatures(texture), cam, model, xy, 0.0, 0.8), 500)
    print(f"ten candidates judged, 320x240 frame: p50 {p50:.3f} ms, p99 {p99:.3f} ms (target 3)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
