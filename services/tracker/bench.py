"""Particle-filter step time against the particle count (targets: 150 particles
<= 100 us, 10 000 <= 2 ms; the thesis needed 85 ms for 150 on an 850 MHz Pentium III), then
the step time of every estimator with its default settings.

A particle-filter step is what the tracker does per scan for one person: ego-motion, propagate
(fresh velocities), weight by range and bearing, normalise, MMSE estimate, resample. An
estimator step (second table, every estimator alike) is ego-motion, predict, distance of three
candidates and gate, update. Median of batches, after a warm-up; printed as tables, or JSON
with --json.

    python -m followbot.services.tracker.bench
    python -m followbot.services.tracker.bench --resampler sorted_copy --counts 150 1000
    python -m followbot.services.tracker.bench --counts --estimators kalman_window nearest
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from .core import se2_change
from .estimators import (
    ParticleEstimator,
    ParticleSettings,
    estimator_factory,
    registry,
    systematic_resample,
)

__all__ = ["COUNTS", "main", "time_estimator_step", "time_step"]

COUNTS = (50, 150, 500, 1000, 3000, 10_000, 30_000)


def time_step(particles: int, resampler: str = "systematic", repeats: int = 0) -> float:
    """Median seconds of one full step (ego-motion, predict, update with resampling)."""
    est = ParticleEstimator(
        2.0,
        0.3,
        ParticleSettings(particles=particles, resampler=resampler),
        np.random.default_rng(0),
    )
    rot, trans = se2_change((0.0, 0.0, 0.0), (0.05, 0.01, 0.02))
    z = np.array([2.0, 0.3])
    repeats = repeats or max(20, min(2000, 400_000 // particles))
    batch = max(1, repeats // 20)
    for _ in range(batch):
        est.ego_motion(rot, trans)
        est.predict(0.12)
        est.update(z)
    samples = []
    for _ in range(20):
        t0 = time.perf_counter()
        for _ in range(batch):
            est.ego_motion(rot, trans)
            est.predict(0.12)
            est.update(z)
        samples.append((time.perf_counter() - t0) / batch)
    return float(np.median(samples))


def time_estimator_step(name: str, repeats: int = 2000) -> float:
    """Median seconds of one step of estimator ``name`` (default settings): ego-motion, predict,
    distance of three candidates and gate, update with the nearest."""
    est = estimator_factory(name)(2.0, 0.3, np.random.default_rng(0))
    rot, trans = se2_change((0.0, 0.0, 0.0), (0.05, 0.01, 0.02))
    z = np.array([[2.0, 0.3], [2.6, -0.4], [1.2, 1.1]])
    batch = max(1, repeats // 20)

    def step() -> None:
        est.ego_motion(rot, trans)
        est.predict(0.12, 0)
        d = est.distance(z, 0)
        est.gate(0)
        est.update(z[int(np.argmin(d))])

    for _ in range(batch):
        step()
    samples = []
    for _ in range(20):
        t0 = time.perf_counter()
        for _ in range(batch):
            step()
        samples.append((time.perf_counter() - t0) / batch)
    return float(np.median(samples))


def time_resampler(particles: int) -> tuple[float, float]:
    """(numpy systematic, filterpy systematic) median seconds, for the DESIGN.md comparison."""
    from filterpy.monte_carlo import systematic_resample as fp_systematic

    rng = np.random.default_rng(0)
    w = rng.random(particles)
    w /= w.sum()
    out = []
    for fn in (lambda: systematic_resample(w, rng), lambda: fp_systematic(w)):
        n = max(5, min(2000, 200_000 // particles))
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        out.append((time.perf_counter() - t0) / n)
    return out[0], out[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--counts", type=int, nargs="*", default=list(COUNTS))
    p.add_argument("--resampler", default="systematic", choices=["systematic", "sorted_copy"])
    p.add_argument(
        "--estimators", nargs="*", default=None, help="estimators to time (default: all)"
    )
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    names = sorted(registry.names()) if a.estimators is None else a.estimators
    rows = []
    for n in a.counts:
        step = time_step(n, a.resampler)
        ours, fp = time_resampler(n)
        rows.append(
            {
                "particles": n,
                "step_us": step * 1e6,
                "resample_numpy_us": ours * 1e6,
                "resample_filterpy_us": fp * 1e6,
            }
        )
    steps = [{"estimator": n, "step_us": time_estimator_step(n) * 1e6} for n in names]
    if a.json:
        print(json.dumps({"resampler": a.resampler, "rows": rows, "estimators": steps}, indent=2))
        return 0
    if rows:
        _print_particle_rows(a.resampler, rows)
    if steps:
        print("estimator step (ego-motion, predict, distance of 3 candidates, update), defaults")
        print(f"{'estimator':>14} {'step us':>10}")
        for r in steps:
            print(f"{r['estimator']:>14} {r['step_us']:>10.1f}")
    return 0


def _print_particle_rows(resampler: str, rows: list[dict]) -> None:
    print(f"particle filter step ({resampler} resampling), median of 20 batches")
    print(f"{'particles':>10} {'step us':>10} {'resample us':>12} {'filterpy us':>12}")
    for r in rows:
        print(
            f"{r['particles']:>10} {r['step_us']:>10.1f} {r['resample_numpy_us']:>12.1f}"
            f" {r['resample_filterpy_us']:>12.1f}"
        )


if __name__ == "__main__":
    raise SystemExit(main())
