"""Timing of the simulator's hot paths (targets: scan <= 1 ms, render <= 5 ms).

    python -m followbot.services.sim.bench

The scene: a 9 x 8 m room, 10 boxes, 40 table/chair legs, 20 walking people (90 circles and
44 segments for the laser), a 360 deg scanner at 0.5 deg (720 beams) and a 320x240 camera.
Prints wall-time medians and 90th percentiles and the median CPU time; asserts nothing
(timings belong in reports, not tests).
"""

from __future__ import annotations

import sys
import time

import msgspec
import numpy as np

from .scenario import Scenario
from .simulation import Simulation

__all__ = ["crowd_scenario", "main"]


def crowd_scenario(n_people: int = 20, seed: int = 1) -> Scenario:
    rng = np.random.default_rng(seed)
    people = []
    for i in range(n_people):
        x, y = float(rng.uniform(1, 7)), float(rng.uniform(-3.5, 3.5))
        goal = [float(rng.uniform(1, 7)), float(rng.uniform(-3.5, 3.5))]
        people.append(
            {
                "id": i,
                "start": [x, y],
                "loop": True,
                "path": [{"kind": "walk", "to": goal}, {"kind": "walk", "to": [x, y]}],
                "appearance": {
                    "shirt_rgb": [int(v) for v in rng.integers(0, 255, 3)],
                    "pattern": ("plain", "stripes", "checks")[i % 3],
                },
            }
        )
    legs = rng.uniform([0.5, -3.8], [7.8, 3.8], (40, 2))
    boxes = rng.uniform([1, -3.5], [7, 3.5], (10, 2))
    data = {
        "name": "bench_crowd",
        "world": {
            "walls": [{"points": [[-1, -4], [8, -4], [8, 4], [-1, 4]], "closed": True}],
            "circles": [{"centre": [float(a), float(b)], "radius_m": 0.03} for a, b in legs],
            "boxes": [{"centre": [float(a), float(b)], "size_m": [0.5, 0.4]} for a, b in boxes],
        },
        "laser": {"fov_deg": 360, "resolution_deg": 0.5},
        "people": people,
    }
    return msgspec.convert(data, Scenario)


def main(frames: int = 300) -> None:
    sim = Simulation(crowd_scenario())
    rows: dict[str, tuple[list[float], list[float]]] = {}

    def timed(name: str, fn) -> None:
        # wall time and this thread's CPU time: on a shared 2-core machine the CPU time is the
        # steadier figure (other processes inflate wall time, not CPU time)
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        wall, cpu = rows.setdefault(name, ([], []))
        wall.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)

    def fresh_cast() -> None:
        sim._cast_at = None  # force a fresh cast
        sim._true_cast()

    for _ in range(frames):
        sim.step(20_000_000)
        sim.people_states()
        timed(f"ray cast, {sim.laser.n_beams} beams", fresh_cast)
        timed("scan noise + LaserScan message", sim.scan)  # on the cached cast
        timed(f"render {sim.camera.width}x{sim.camera.height}", sim.image_pixels)
    for name, (wall, cpu) in rows.items():
        w, c = np.asarray(wall) * 1e3, np.asarray(cpu) * 1e3
        sys.stdout.write(
            f"{name:34s} median {np.median(w):6.3f} ms   p90 {np.percentile(w, 90):6.3f} ms"
            f"   cpu median {np.median(c):6.3f} ms\n"
        )


if __name__ == "__main__":
    main()
