"""Top-down and range-over-time plots of one tracking run's people and target.

    python -m followbot.research.track_plot out/x/runs/thesis/demo_stationary \
        --until 60 --output docs/img/demo_target.png

Reads the run's ``people.csv`` and ``target.csv`` (``followbot track`` / ``followbot
benchmark`` write them; x/y in the base frame, which is the laser frame on the recordings
without a tf) and draws, left, every published track as a grey line and the target's
positions coloured by time, the laser at the origin; right, each track's range over time
with the target on top, so a gap in the target and a person seen where it went are seen at a
glance. ``--until`` / ``--since`` limit the time shown (seconds from the first scan).
``--scans RECORDING --at T,T,...`` adds a row of snapshots: the laser's points at the scan
nearest each time, with the tracks of the 1 s before it and the target then (is the person
still in the laser's view where the target was lost?); the target then is ringed red.
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

__all__ = ["main", "read_rows"]


def read_rows(path: Path) -> list[tuple[int, int, float, float]]:
    """(stamp_ns, id, x_m, y_m) of each row of a people.csv / target.csv."""
    with open(path, newline="") as f:
        return [
            (int(r["stamp_ns"]), int(r["id"]), float(r["x_m"]), float(r["y_m"]))
            for r in csv.DictReader(f)
        ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="folder with people.csv and target.csv")
    p.add_argument("--output", type=Path, required=True)
    p.add_argument("--since", type=float, default=0.0)
    p.add_argument("--until", type=float, default=None)
    p.add_argument("--title", default=None)
    p.add_argument("--scans", type=Path, default=None, help="the recording, for --at")
    p.add_argument("--at", default="", help="snapshot times (s from the first scan), a,b,c")
    a = p.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    people = read_rows(a.run / "people.csv")
    target = read_rows(a.run / "target.csv")
    t0 = min(r[0] for r in people + target)
    until = np.inf if a.until is None else a.until

    def keep(rows):
        return [
            ((s - t0) / 1e9, i, x, y) for s, i, x, y in rows if a.since <= (s - t0) / 1e9 <= until
        ]

    people, target = keep(people), keep(target)
    tracks: dict[int, list] = defaultdict(list)
    for row in people:
        tracks[row[1]].append(row)
    at = [float(x) for x in a.at.split(",") if x]
    rows = 2 if a.scans is not None and at else 1
    fig = plt.figure(figsize=(14, 6.5 * rows))
    grid = fig.add_gridspec(rows, max(len(at), 2))
    half = max(len(at), 2) // 2
    top, rng = fig.add_subplot(grid[0, :half]), fig.add_subplot(grid[0, half:])
    for track in tracks.values():
        arr = np.array([(x, y) for _, _, x, y in track])
        top.plot(arr[:, 0], arr[:, 1], color="0.6", lw=0.6, alpha=0.6)
        t = np.array([r[0] for r in track])
        rng.plot(t, np.hypot(arr[:, 0], arr[:, 1]), color="0.6", lw=0.6, alpha=0.6)
    if target:
        tt = np.array([r[0] for r in target])
        xy = np.array([(x, y) for _, _, x, y in target])
        sc = top.scatter(xy[:, 0], xy[:, 1], c=tt, s=6, cmap="viridis", zorder=3)
        fig.colorbar(sc, ax=top, label="time of the target's position (s)")
        ids = np.array([r[1] for r in target])
        rng.scatter(tt, np.hypot(xy[:, 0], xy[:, 1]), c=ids % 10, cmap="tab10", s=5, zorder=3)
    if rows == 2:
        snaps = _scans_at(a.scans, t0, at)
        for k, (when, pts) in enumerate(snaps):
            ax = fig.add_subplot(grid[1, k])
            _snapshot(ax, when, pts, tracks, target)
    top.plot([0], [0], "k^", ms=9)
    top.set_aspect("equal")
    top.set_xlabel("x (m, laser frame)")
    top.set_ylabel("y (m)")
    top.set_title("tracks (grey), the target (coloured by time)")
    rng.set_xlabel("time (s)")
    rng.set_ylabel("range from the laser (m)")
    rng.set_title("range over time: tracks (grey), target (colour = its track id)")
    fig.suptitle(a.title or str(a.run))
    fig.tight_layout()
    a.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.output, dpi=90)
    print(f"wrote {a.output}")
    return 0


def _scans_at(path: Path, t0: int, at: list[float]) -> list[tuple[float, np.ndarray]]:
    """(time, points (k, 2) in the laser frame) of the scan nearest each of ``at``."""
    from followbot.bags import open_recording

    want = sorted(at)
    best: dict[float, tuple[float, object]] = {}
    for _, topic, m in open_recording(path).messages():
        if topic != "sensors/scan":
            continue
        t = (m.stamp_ns - t0) / 1e9
        for w in want:
            if w not in best or abs(t - w) < abs(best[w][0] - w):
                best[w] = (t, m)
        if t > want[-1] + 1.0:
            break
    out = []
    for w in at:
        t, m = best[w]
        r = np.asarray(m.ranges.numpy() if hasattr(m.ranges, "numpy") else m.ranges, dtype=float)
        ang = m.angle_min_rad + m.angle_increment_rad * np.arange(r.shape[0])
        ok = np.isfinite(r) & (r > m.range_min_m) & (r < m.range_max_m)
        out.append((t, np.c_[r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])]))
    return out


def _snapshot(ax, when: float, pts: np.ndarray, tracks: dict, target: list) -> None:
    ax.scatter(pts[:, 0], pts[:, 1], s=1, color="k")
    for rows in tracks.values():
        near = [(x, y) for t, _, x, y in rows if when - 1.0 <= t <= when]
        if near:
            arr = np.array(near)
            ax.plot(arr[:, 0], arr[:, 1], color="tab:blue", lw=1)
            ax.plot(arr[-1, 0], arr[-1, 1], "o", color="tab:blue", ms=3)
    now = [(x, y) for t, _, x, y in target if abs(t - when) < 0.06]
    if now:
        ax.plot(now[0][0], now[0][1], "o", mfc="none", mec="r", ms=14, mew=2)
    ax.plot([0], [0], "k^", ms=7)
    ax.set_xlim(-0.5, 5.5)
    ax.set_ylim(-4, 4)
    ax.set_aspect("equal")
    ax.set_title(f"{when:.1f} s: scan, last 1 s of tracks", fontsize=9)


if __name__ == "__main__":
    raise SystemExit(main())
