"""How good laser_odometry's poses are on the real recordings (docs/laser_odometry.md).

    python -m followbot.research.laser_odometry_eval [--data DIR] [--set KEY=VALUE ...]

The service's own core (:class:`ScanOdometry`) in process, no Zenoh, on:

- carmen/*.log.gz: each FLASER scan's laser pose against the log's corrected (SLAM) laser
  pose. Over every stretch of ``WINDOW_M`` of true path: the error of the relative pose at its
  end, translation (% of the path) and heading (deg per m); the same per second where the log's
  stamps are usable. (The logs' odometry fields are corrected too: scored the same way they
  show no error, so they are no wheel-odometry baseline.)
- legs360 and demo_stationary (a still laser): how far the pose drifts, at the end and at most.
- negative_2 (moving, no ground truth): how still the world looks. Each scan's returns are put
  in the odometry frame; their distance to the nearest return of the scan ``LAG_S`` earlier
  (also in that frame), median, with the poses and without (every pose at zero: the world
  seems to move with the robot); and how far the three lasers' headings part (they sit on
  one robot, so they differ by a constant).
"""

from __future__ import annotations

import argparse
import gzip
import math
from pathlib import Path

import numpy as np

from followbot.schemas import LaserScan

WINDOW_M = 5.0
LAG_S = 1.0


def _settings(overrides: list[str]):
    from followbot.services.laser_odometry.settings import LaserOdometrySettings
    from followbot.services.runtime.settings import load_settings

    return load_settings(LaserOdometrySettings, None, overrides)


def carmen_scans(path: Path):
    """(scans, corrected laser poses, seconds from the first scan or None when the stamps are
    unusable) of a log's FLASER records."""
    from followbot.carmen import CarmenLog, Malformed, flaser_geometry, parse_line

    ceiling = CarmenLog(path).no_return_m.get("FLASER", 80.0)
    scans, truth = [], []
    with gzip.open(path, "rt", encoding="latin-1") as f:
        for line in f:
            tokens = line.split()
            if not tokens or tokens[0] != "FLASER":
                continue
            try:
                rec = parse_line(tokens)
            except Malformed:
                continue
            r = np.where((rec.ranges >= ceiling) | (rec.ranges < 0), np.inf, rec.ranges)
            amin, inc = flaser_geometry(len(r))
            truth.append(rec.laser_pose)
            scans.append((rec.stamp_ns, r.astype(np.float32), amin, inc, ceiling))
    stamps = np.array([s[0] for s in scans])
    seconds = (stamps - stamps[0]) / 1e9 if np.all(np.diff(stamps) > 0) else None
    out = []
    for k, (_stamp, r, amin, inc, ceiling) in enumerate(scans):
        # The logs keep a scan per ~1 m travelled, not per time (and three have no usable
        # stamps): stamped 0.1 s apart (a 10 Hz laser's), the constant-velocity guess is the
        # last step and the settings' times keep their meaning in scans.
        st = (k + 1) * 100_000_000
        out.append(LaserScan.from_ranges(r, stamp_ns=st, frame_id="front_laser",
                                         angle_min_rad=amin, angle_increment_rad=inc,
                                         range_min_m=0.0, range_max_m=ceiling))  # fmt: skip
    return out, np.array(truth), seconds


def run_poses(scans, settings) -> tuple[np.ndarray, dict]:
    from followbot.services.laser_odometry.core import ScanOdometry

    odo = ScanOdometry(settings)
    poses = np.array([odo.update(s).pose for s in scans])
    return poses, dict(odo.counts)


def _relative(p: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Poses j in the frames of poses i (arrays of indices)."""
    c, s = np.cos(p[i, 2]), np.sin(p[i, 2])
    dx, dy = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
    dth = np.angle(np.exp(1j * (p[j, 2] - p[i, 2])))
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, dth])


def window_errors(est, truth, seconds, window_m: float = WINDOW_M) -> dict:
    """Median relative-pose errors over every stretch of ``window_m`` of true path."""
    step = np.hypot(*np.diff(truth[:, :2], axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(step)])
    i = np.arange(len(truth))
    j = np.searchsorted(cum, cum + window_m)
    keep = j < len(truth)
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return {}
    rt, re = _relative(truth, i, j), _relative(est, i, j)
    path = cum[j] - cum[i]
    et = np.hypot(re[:, 0] - rt[:, 0], re[:, 1] - rt[:, 1])
    eh = np.degrees(np.abs(np.angle(np.exp(1j * (re[:, 2] - rt[:, 2])))))
    out = {"trans_pct": float(np.median(et / path) * 100), "heading_deg_per_m": float(
        np.median(eh / path))}  # fmt: skip
    if seconds is not None:
        dt = seconds[j] - seconds[i]
        out["trans_m_per_s"] = float(np.median(et / dt))
        out["heading_deg_per_s"] = float(np.median(eh / dt))
    return out


def carmen(data: Path, settings) -> None:
    print(f"CARMEN FLASER, relative pose error over {WINDOW_M:g} m of true path (medians)")
    print("| log | scans | failed | trans % of path | deg/m | m/s | deg/s |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for path in sorted(data.glob("carmen/*.log.gz")):
        scans, truth, secs = carmen_scans(path)
        ok = secs is not None
        est, counts = run_poses(scans, settings)
        e = window_errors(est, truth, secs)
        rows.append(e)
        per_s = (f"{e['trans_m_per_s']:.4f} | {e['heading_deg_per_s']:.3f}" if ok
                 else "- | -")  # fmt: skip
        print(f"| {path.name.split('-corrected')[0]} | {len(scans)} | {counts['failed']} | "
              f"{e['trans_pct']:.2f} | {e['heading_deg_per_m']:.3f} | {per_s} |")  # fmt: skip

    def med(key):
        vals = [r[key] for r in rows if key in r]
        return float(np.median(vals)) if vals else float("nan")

    print(f"| **median of the logs** | | | {med('trans_pct'):.2f} | "
          f"{med('heading_deg_per_m'):.3f} | {med('trans_m_per_s'):.4f} | "
          f"{med('heading_deg_per_s'):.3f} |")  # fmt: skip


def bag_scans(path: Path, topic: str) -> list[LaserScan]:
    from followbot.bags import open_recording

    rec = open_recording(path, {topic: "sensors/scan"})
    return [m for _, t, m in rec.messages() if t == "sensors/scan"]


def still(data: Path, settings) -> None:
    print("\nStill laser: drift of the pose (end / most, translation and heading)")
    for path, topic in (
        (data / "legs360/legs360.bag", "/scan"),
        (data / "leg_tracker/demo_stationary_simple_environment.bag", "/scan"),
    ):
        scans = bag_scans(path, topic)
        poses, counts = run_poses(scans, settings)
        d = np.hypot(poses[:, 0], poses[:, 1])
        h = np.degrees(np.abs(poses[:, 2]))
        span = (scans[-1].stamp_ns - scans[0].stamp_ns) / 1e9
        print(f"  {path.name}: {len(scans)} scans over {span:.0f} s; end {d[-1] * 1000:.1f} mm "
              f"{h[-1]:.3f} deg; most {d.max() * 1000:.1f} mm {h.max():.3f} deg; "
              f"keyframes {counts['keyframes']}, failed {counts['failed']}")  # fmt: skip


def _points(scan: LaserScan, pose) -> np.ndarray:
    r = np.asarray(scan.ranges_m(), dtype=np.float64)
    a = scan.angle_min_rad + scan.angle_increment_rad * np.arange(len(r))
    ok = np.isfinite(r) & (r > scan.range_min_m) & (r < scan.range_max_m)
    x, y = r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([c * x - s * y + pose[0], s * x + c * y + pose[1]])


def world_spread(scans, poses, lag: int) -> float:
    """Median distance of each scan's returns to the nearest return ``lag`` scans earlier, both
    in the frame of ``poses``."""
    from scipy.spatial import cKDTree

    dists = []
    for k in range(lag, len(scans), 5):
        a, b = _points(scans[k], poses[k]), _points(scans[k - lag], poses[k - lag])
        if len(a) and len(b):
            dists.append(cKDTree(b).query(a)[0])
    return float(np.median(np.concatenate(dists)))


def moving(data: Path, settings) -> None:
    print(f"\nnegative_2: returns' distance to the nearest return {LAG_S:g} s earlier (median)")
    yaws = {}
    for topic in ("/left_scan", "/rear_scan", "/right_scan"):
        scans = bag_scans(data / "leg_tracker/negative_2.bag", topic)
        poses, counts = run_poses(scans, settings)
        yaws[topic] = (np.array([s.stamp_ns for s in scans]) / 1e9, np.unwrap(poses[:, 2]))
        dt = np.median(np.diff([s.stamp_ns for s in scans])) / 1e9
        lag = max(1, round(LAG_S / dt))
        with_odo = world_spread(scans, poses, lag)
        without = world_spread(scans, np.zeros_like(poses), lag)
        path = np.hypot(*np.diff(poses[:, :2], axis=0).T).sum()
        turn = np.degrees(np.abs(np.angle(np.exp(1j * np.diff(poses[:, 2])))).sum())
        print(f"  {topic}: {len(scans)} scans; with laser odometry {with_odo * 100:.1f} cm, "
              f"without {without * 100:.1f} cm; path {path:.1f} m, turned {turn:.0f} deg; "
              f"failed {counts['failed']}, refused {counts['refused']}, recovered "
              f"{counts['recovered']}")  # fmt: skip
    # the three lasers sit on one robot: their headings differ by a constant, the mounts'
    t, _ = yaws["/left_scan"]
    for a, b in (("/left_scan", "/right_scan"), ("/left_scan", "/rear_scan"),
                 ("/rear_scan", "/right_scan")):  # fmt: skip
        d = np.degrees(np.interp(t, *yaws[a]) - np.interp(t, *yaws[b]))
        d -= d[0]
        print(f"  heading {a} - {b}: end {d[-1]:+.2f} deg, most {np.abs(d).max():.2f} deg")


def main(argv: list[str] | None = None) -> int:
    from followbot.benchmark import default_data_dir

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=None, help="the data folder (shared/data)")
    p.add_argument("--set", action="append", default=[], help="a laser_odometry setting")
    p.add_argument("--only", nargs="*", default=["carmen", "still", "moving"])
    args = p.parse_args(argv)
    data = args.data or default_data_dir()
    settings = _settings(args.set)
    for name, fn in (("carmen", carmen), ("still", still), ("moving", moving)):
        if name in args.only:
            fn(data, settings)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
