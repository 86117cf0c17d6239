"""Measurements on CARMEN logs: how well a beam geometry fits the corrected poses, and how
fast followbot reads them.

Every FLASER scan is put into the map at its corrected laser pose (``x y theta``) with a beam
geometry (first beam angle, step); the residual is the mean distance from each point of a scan
to the nearest point of the scans up to ``WINDOW`` before and after it (capped at ``CAP_M``, so
what only one scan sees does not swamp the sum). The right geometry makes walls seen from
different places coincide: the smaller the residual, the better the fit.

Reading speed: the scans per second of opening a log and reading all its messages
(:func:`followbot.bags.open_recording`, default sources), best of ``REPEATS``.

    python tests/carmen_logs.py [LOG ...]     # the tables of docs/recording.md
"""

from __future__ import annotations

import gzip
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from followbot.carmen import Malformed, flaser_geometry, parse_line

WINDOW = 3
CAP_M = 0.3
#: Points used: returns nearer than this (and than the scanner's ceiling).
MAX_RANGE_M = 20.0


@dataclass(frozen=True)
class Scan:
    ranges: np.ndarray
    pose: tuple[float, float, float]


def flaser_scans(path: Path) -> list[Scan]:
    """The FLASER scans of a log with their corrected laser poses, in file order."""
    opener = gzip.open if path.name.endswith(".gz") else open
    out = []
    with opener(path, "rt", encoding="latin-1") as f:
        for line in f:
            tokens = line.split()
            if tokens and tokens[0] == "FLASER":
                try:
                    rec = parse_line(tokens)
                except Malformed:
                    continue
                out.append(Scan(rec.ranges, rec.laser_pose))
    return out


def residual_m(scans: list[Scan], angle_min_rad: float, step_rad: float) -> float:
    """Mean capped distance (m) from each scan's points to its neighbours' (see above)."""
    from scipy.spatial import cKDTree

    points = []
    for scan in scans:
        r = scan.ranges
        bearing = angle_min_rad + step_rad * np.arange(len(r))
        ok = (r > 0.0) & (r < MAX_RANGE_M)
        x, y, yaw = scan.pose
        a = bearing[ok] + yaw
        points.append(np.c_[x + r[ok] * np.cos(a), y + r[ok] * np.sin(a)])
    total, count = 0.0, 0
    for k, pts in enumerate(points):
        near = [points[j] for j in range(max(0, k - WINDOW), k + WINDOW + 1)
                if j != k and j < len(points) and len(points[j])]  # fmt: skip
        if not near or not len(pts):
            continue
        d, _ = cKDTree(np.vstack(near)).query(pts)
        total += float(np.minimum(d, CAP_M).sum())
        count += len(d)
    return total / count


def candidates(n: int) -> dict[str, tuple[float, float]]:
    """The geometries an ``n``-beam scan over 180 deg could have: name -> (first angle, step).
    The first is the reader's (:func:`followbot.carmen.flaser_geometry`)."""
    chosen = flaser_geometry(n)
    half = math.pi / 2
    if n % 2:  # both ends in, or one left out
        return {
            "both ends, -90..+90 (chosen)": chosen,
            "-90 deg end left out": (-half + math.pi / n, math.pi / n),
            "+90 deg end left out": (-half, math.pi / n),
        }
    return {
        "+90 deg end left out (chosen)": chosen,
        "-90 deg end left out": (-half + math.pi / n, math.pi / n),
        "centred, half a step in from each end": (-half + math.pi / (2 * n), math.pi / n),
        "both ends, spread over 180 deg": (-half, math.pi / (n - 1)),
    }


def best_fit(scans: list[Scan]) -> tuple[float, float]:
    """The first-beam angle (deg) and step scale that fit best, each varied alone around the
    reader's geometry (0.1 deg and 0.2 % steps) with a parabola through the residuals."""
    start, step = flaser_geometry(len(scans[0].ranges))
    offsets = np.arange(-0.6, 0.61, 0.1)
    r = [residual_m(scans, start + math.radians(o), step) for o in offsets]
    a, b, _ = np.polyfit(offsets, r, 2)
    scales = np.linspace(0.994, 1.006, 7)
    r = [residual_m(scans, start, step * s) for s in scales]
    a2, b2, _ = np.polyfit(scales, r, 2)
    return math.degrees(start) - b / (2 * a), -b2 / (2 * a2)


def table(paths: list[Path]) -> str:
    rows = ["| log | beams | geometry | residual (mm) |", "|---|---|---|---|"]
    for path in paths:
        scans = flaser_scans(path)
        n = len(scans[0].ranges)
        for name, (start, step) in candidates(n).items():
            mm = 1000 * residual_m(scans, start, step)
            rows.append(f"| {path.name.split('-corrected')[0]} | {n} | {name} | {mm:.1f} |")
    return "\n".join(rows)


REPEATS = 3


def reading_speed(paths: list[Path]) -> str:
    from followbot.bags import open_recording

    rows = ["| log | scans | lines | read (s) | scans/s |", "|---|---|---|---|---|"]
    for path in paths:
        best = math.inf
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            rec = open_recording(path)
            scans = sum(1 for _, topic, _ in rec.messages() if topic == "sensors/scan")
            best = min(best, time.perf_counter() - t0)
        lines = rec.carmen.bad.lines_read
        name = path.name.split("-corrected")[0]
        rows.append(f"| {name} | {scans} | {lines} | {best:.2f} | {scans / best:.0f} |")
    return "\n".join(rows)


def odometry_frames(paths: list[Path]) -> str:
    """How far apart the ODOM lines and a FLASER's odometry fields put the robot at the scans'
    stamps (logs whose scans keep their own stamps)."""
    from followbot.carmen import CarmenLog

    rows = ["| log | median (m) | max (m) |", "|---|---|---|"]
    for path in paths:
        log = CarmenLog(path)
        if log.restamped:
            continue
        odom, laser = [], []
        for t, src, m in log.messages(["ODOM", "FLASER/odom"]):
            (odom if src == "ODOM" else laser).append((t, m.x_m, m.y_m))
        o, f = np.array(odom), np.array(laser)
        x = np.interp(f[:, 0], o[:, 0], o[:, 1])
        y = np.interp(f[:, 0], o[:, 0], o[:, 2])
        d = np.hypot(x - f[:, 1], y - f[:, 2])
        name = path.name.split("-corrected")[0]
        rows.append(f"| {name} | {np.median(d):.2f} | {d.max():.1f} |")
    return "\n".join(rows)


def fits(paths: list[Path]) -> str:
    rows = ["| log | beams | best first-beam angle (deg) | best step / reader's step |",
            "|---|---|---|---|"]  # fmt: skip
    for path in paths:
        scans = flaser_scans(path)
        angle, scale = best_fit(scans)
        name = path.name.split("-corrected")[0]
        rows.append(f"| {name} | {len(scans[0].ranges)} | {angle:+.3f} | {scale:.4f} |")
    return "\n".join(rows)


if __name__ == "__main__":
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"
    logs = [Path(p) for p in sys.argv[1:]] or sorted(default.glob("*.log.gz"))
    print(reading_speed(logs))
    print()
    print(odometry_frames(logs))
    print()
    print(table(logs))
    print()
    print(fits(logs))
