"""Timing of the histogram verifier (printed, never asserted): ``python -m
followbot.services.vision_verify.bench [--rounds N]``.

* both histograms of one 100 x 200 patch (DESIGN.md target <= 0.3 ms);
* ten candidates of one 320 x 240 frame judged against a model (target <= 3 ms), including the
  per-frame colour conversion and bin lookup shared by the rectangles.

Each figure is timed for the fast path (core.py) and for the plain computation it replaced
(reference.py) in the same run, alternating in rounds so both see the same machine load; it
reports the median wall time and the median CPU time of the thread (which leaves out time
spent waiting for a core, not the cost of caches shared with other processes). The two paths
must give the same histograms and distances; the bench says so, or exits 1.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from .core import Camera, ImageFeatures, Model, colour_histogram, edge_histogram, judge
from .reference import ReferenceFeatures, ReferenceHistogramVerifier
from .verifiers.histogram import HistogramVerifier


def _times(fn, n: int, wall: list[float], cpu: list[float]) -> None:
    for _ in range(n):
        t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
        fn()
        c1, t1 = time.thread_time_ns(), time.perf_counter_ns()
        wall.append((t1 - t0) / 1e6)
        cpu.append((c1 - c0) / 1e6)


def _race(fast, ref, n: int, rounds: int) -> dict[str, float]:
    """Median wall and CPU ms of ``fast`` and ``ref``, timed alternately in ``rounds`` rounds."""
    fast(), ref()  # warm-up: lazy tables, scratch buffers
    fw, fc, rw, rc = [], [], [], []
    for _ in range(rounds):
        _times(fast, n, fw, fc)
        _times(ref, n, rw, rc)
    med = np.median
    return {
        "fast_wall": float(med(fw)),
        "fast_cpu": float(med(fc)),
        "ref_wall": float(med(rw)),
        "ref_cpu": float(med(rc)),
        "fast_wall_p90": float(np.percentile(fw, 90)),
    }


def _line(what: str, r: dict[str, float], target: float) -> str:
    return (
        f"{what}: fast p50 {r['fast_wall']:.3f} ms wall / {r['fast_cpu']:.3f} ms CPU "
        f"(p90 wall {r['fast_wall_p90']:.3f}); reference p50 {r['ref_wall']:.3f} ms wall / "
        f"{r['ref_cpu']:.3f} ms CPU; speed-up {r['ref_cpu'] / r['fast_cpu']:.1f}x CPU; "
        f"target {target} ms: {'met' if r['fast_wall'] <= target else 'NOT met'} (wall p50)"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m followbot.services.vision_verify.bench")
    ap.add_argument("--rounds", type=int, default=10, help="alternations of fast and reference")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)  # one core, as the target says
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), (7, 7), 2)
    patch = np.ascontiguousarray(texture[20:220, 100:200])  # 100 wide x 200 high
    whole = (0, 0, 100, 200)

    def fast_patch():
        return colour_histogram(patch), edge_histogram(patch)

    def ref_patch():
        r = ReferenceFeatures(patch)
        return r.colour(whole), r.edges(whole)

    same = all(np.array_equal(a, b) for a, b in zip(fast_patch(), ref_patch(), strict=True))
    r = _race(fast_patch, ref_patch, 200, args.rounds)
    print(_line("both histograms, 100x200 patch", r, 0.3))

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
    fast_v, ref_v = HistogramVerifier(), ReferenceHistogramVerifier()

    def fast_judge():
        return judge(fast_v, ImageFeatures(texture), cam, model, xy, 0.0, 0.8)

    def ref_judge():
        return judge(ref_v, ReferenceFeatures(texture), cam, model, xy, 0.0, 0.8)

    same = same and fast_judge().distances == ref_judge().distances
    r = _race(fast_judge, ref_judge, 50, args.rounds)
    print(_line("ten candidates judged, 320x240 frame", r, 3.0))
    print(f"fast and reference results identical: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
