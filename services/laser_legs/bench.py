"""Time per scan of every detector: ``python -m followbot.services.laser_legs.bench``.

Synthetic 720-beam scan (0.5 deg over 360 deg) of a room with two persons and a post, 1 cm
range noise; median of many calls after a warm-up (the machine is shared and noisy: the median
is the figure, the minimum shows the floor). Also the robot-body filter the node runs in front
of every detector (``self_filter``), on a stream of that room turning past a 20-beam body, and
the ``horizon`` the node sends with every scan's candidates.

Each detector call alternates with one reference call: a numpy ufunc on the scan's 720 float64
ranges (``np.add``), the unit the detectors' cost is made of. This shared machine's speed
wanders by +-30 % (at times 2x) from one second to the next; a detector's median divided by the
reference's median over the same calls moves far less (``median / reference``: the ``thesis``
detector costs about 40-60 such calls). The last row is the reference over every detector's
calls.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from followbot.schemas import LaserScan

from .beams import horizon
from .detectors import DETECTORS, make_detector
from .scene import make_scan, person_legs
from .self_filter import RobotBodyFilter

#: Where the bench scan's first person stands (x, y in m).
BENCH_PERSON = (1.5, 0.3)


def bench_scan(n_beams: int = 720):
    room = [(3, -3, 3, 3), (3, 3, -3, 3), (-3, 3, -3, -3), (-3, -3, 3, -3)]
    people = [*person_legs(*BENCH_PERSON), *person_legs(2.5, -1.0), (1.0, 1.5, 0.05)]
    inc = 2 * math.pi / n_beams
    return make_scan(
        people,
        room,
        fov_rad=inc * (n_beams - 1),
        increment_rad=inc,
        angle_min_rad=-math.pi,
        noise_m=0.01,
        rng=np.random.default_rng(1),
    )


def _timed(call, repeats: int) -> tuple[float, float]:
    """(median, min) µs of ``call(i)`` for i in range(repeats)."""
    clock = time.perf_counter
    ts = np.empty(repeats)
    for i in range(repeats):
        t0 = clock()
        call(i)
        ts[i] = clock() - t0
    return float(np.median(ts) * 1e6), float(ts.min() * 1e6)


def reference_call(scan):
    """One ``np.add`` of two float64 arrays of the scan's length into a preallocated output: a
    numpy call's fixed cost, which dominates the detectors' time at this size."""
    a = scan.ranges.numpy().astype(np.float64)
    out = np.empty_like(a)
    return lambda: np.add(a, a, out=out)


def time_detector(
    name: str, scan, repeats: int = 3000, warmup: int = 200, prediction=None
) -> tuple[float, float, np.ndarray]:
    """(median µs, min µs, the reference call's times in s) of ``detect`` on ``scan`` (with
    criterion 3's ``prediction``), each detector call followed by one reference call."""
    det = make_detector(name)
    ref = reference_call(scan)
    for _ in range(warmup):
        det.detect(scan, prediction)
        ref()
    clock = time.perf_counter
    ts = np.empty(repeats)
    rs = np.empty(repeats)
    for i in range(repeats):
        t0 = clock()
        det.detect(scan, prediction)
        t1 = clock()
        ref()
        rs[i] = clock() - t1
        ts[i] = t1 - t0
    return float(np.median(ts) * 1e6), float(ts.min() * 1e6), rs


def time_self_filter(scan, repeats: int = 3000) -> tuple[float, float]:
    """The body filter per scan once it knows the body: the room turns 1 beam per scan."""
    base = scan.ranges.numpy().copy()
    base[:20] = 0.3

    def turned(k: int) -> LaserScan:
        r = np.roll(base, k)
        r[:20] = 0.3
        return LaserScan.from_ranges(
            r,
            stamp_ns=(k + 1) * 25_000_000,
            angle_min_rad=scan.angle_min_rad,
            angle_increment_rad=scan.angle_increment_rad,
        )

    f = RobotBodyFilter()
    for k in range(200):
        f.update(turned(k))
    scans = [turned(200 + i) for i in range(repeats)]
    return _timed(lambda i: f.update(scans[i]), repeats)


def time_horizon(scan, repeats: int = 3000) -> tuple[float, float]:
    """The candidates' ``horizon`` (1-degree bins), which the node adds to every message."""
    for _ in range(200):
        horizon(scan)
    return _timed(lambda _i: horizon(scan), repeats)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--beams", type=int, default=720, help="beams of the bench scan (default 720)")
    p.add_argument("--repeats", type=int, default=3000, help="timed calls per row (default 3000)")
    p.add_argument(
        "--warmup", type=int, default=200, help="untimed calls per detector first (default 200)"
    )
    args = p.parse_args(argv)
    scan = bench_scan(args.beams)
    refs = []
    sys.stdout.write(
        f"| detector | median us/scan ({args.beams} beams) | min us | median / reference |\n"
        "|---|---|---|---|\n"
    )
    rows = [(name, name, None) for name in DETECTORS]
    # the node gates on the tracked target's prediction (criterion 3) while it is tracked:
    # thesis then also anchors its pairing there (the first bench person, legs 0.3 m apart)
    rows.insert(1, ("thesis (tracking: criterion 3 at a person)", "thesis", BENCH_PERSON))
    for label, name, prediction in rows:
        med, lo, ref = time_detector(name, scan, args.repeats, args.warmup, prediction)
        refs.append(ref)
        ratio = med / (float(np.median(ref)) * 1e6)
        sys.stdout.write(f"| {label} | {med:.0f} | {lo:.0f} | {ratio:.0f} |\n")
    med, lo = time_self_filter(scan, args.repeats)
    sys.stdout.write(f"| (robot-body filter, node default) | +{med:.0f} | +{lo:.0f} |\n")
    med, lo = time_horizon(scan, args.repeats)
    sys.stdout.write(f"| (horizon for the tracker, node default) | +{med:.0f} | +{lo:.0f} |\n")
    ref = np.concatenate(refs) * 1e6
    sys.stdout.write(
        f"| (reference: one numpy call on {scan.ranges.shape[0]} floats) | "
        f"{float(np.median(ref)):.2f} | {float(ref.min()):.2f} | 1 |\n"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
