"""How the ``learned`` forest scores the simulator's legs against real labelled legs.

    python -m followbot.research.sim_legs [--model FILE] [--scenario NAME ...]

Runs each scenario in process (the robot standing where it starts; only the scans matter) and
scores every segment of every scan with the forest alone (no static background, no leg
tracks, no prediction gate). A simulated leg with at least 3 returns within 0.1 m of its centre
and within 8 m is matched to the best-scoring segment whose centroid lies within 0.15 m of it
(the real held-out legs, positive_6 and positive_7, the same way against their labels). Prints
per scenario the share of legs scoring ``threshold`` (0.10) or more and the median score, by
range and by how many other segments lie within 1 m (``segments_within_1m``), and the
median of each feature over the legs at 1-3 m, simulated beside real (issue 35,
docs/laser_legs.md "Issue 35, the simulator's legs").
"""

from __future__ import annotations

import argparse
import math
import sys

import msgspec
import numpy as np

from followbot.schemas import GroundTruth, LaserScan
from followbot.services.laser_legs.detectors.learned import (
    FEATURES,
    LearnedSettings,
    RandomTreesLegDetector,
    features_and_centroids,
    segments,
)
from followbot.services.sim.scenario import load_builtin
from followbot.services.sim.simulation import Simulation

__all__ = ["leg_rows", "main", "real_rows"]

SCENARIOS = (
    "thesis_5_2_4_two_people",
    "thesis_5_2_4_side_by_side",
    "occlusion_pillar",
    "crowd_ten",
    "furnished_office",
)
MATCH_M = 0.15
RANGE_BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 5.0), (5.0, 8.0))


def _scored(det: RandomTreesLegDetector, scan: LaserScan):
    s = det.settings
    seg = segments(
        scan, s.cluster_gap_m, s.min_points, s.max_width_m, s.max_range_m, s.dropout_beams
    )
    f, cx, cy = features_and_centroids(seg)
    return f, cx, cy, det.leg_scores(f)


def _match(f, cx, cy, score, lx: float, ly: float) -> tuple[float, np.ndarray | None]:
    """(score, features) of the best segment within MATCH_M of (lx, ly); (-1, None): none."""
    ok = np.hypot(cx - lx, cy - ly) <= MATCH_M
    if not ok.any():
        return -1.0, None
    i = int(np.argmax(np.where(ok, score, -9.0)))
    return float(score[i]), f[i]


def leg_rows(det: RandomTreesLegDetector, name: str) -> list[tuple[float, float, np.ndarray]]:
    """(range, score, features) of every simulated leg seen by at least 3 returns."""
    sc = load_builtin(name)
    sim = Simulation(sc)
    rows, scan = [], None
    while not sim.finished:
        for m in sim.tick():
            if isinstance(m, LaserScan):
                scan = m
            elif isinstance(m, GroundTruth) and scan is not None:
                f, cx, cy, score = _scored(det, scan)
                r, a = scan.ranges_m(), scan.angles_rad()
                ok = np.isfinite(r)
                x, y = np.where(ok, r, 0) * np.cos(a), np.where(ok, r, 0) * np.sin(a)
                for p in m.people:
                    for lx, ly in np.asarray(p.legs_robot_m).reshape(-1, 2):
                        lx -= sc.laser.mount_x_m
                        rho = math.hypot(lx, ly)
                        if rho > 8.0 or (ok & (np.hypot(x - lx, y - ly) < 0.1)).sum() < 3:
                            continue
                        rows.append((rho, *_match(f, cx, cy, score, lx, ly)))
                scan = None
    return rows


def real_rows(det: RandomTreesLegDetector) -> list[tuple[float, float, np.ndarray]]:
    """(range, score, features) of every labelled leg of the held-out positive bags."""
    from followbot.research.realdata import HELD_OUT_POSITIVES, read_positive

    rows = []
    for n in HELD_OUT_POSITIVES:
        for it in read_positive(n):
            f, cx, cy, score = _scored(det, it.scan)
            for lx, ly in it.legs_xy:
                rows.append((math.hypot(lx, ly), *_match(f, cx, cy, score, lx, ly)))
    return rows


def _summary(label: str, rows, threshold: float) -> list[str]:
    rho = np.array([r[0] for r in rows])
    sc = np.array([r[1] for r in rows])
    j = FEATURES.index("segments_within_1m")
    near = np.array([-1 if r[2] is None else r[2][j] for r in rows])
    out = [f"{label}: {len(rows)} legs, score >= {threshold:g} {np.mean(sc >= threshold):.3f}, "
           f"median {np.median(sc):.3f}"]  # fmt: skip
    parts = [(f"{lo:g}-{hi:g} m", (rho >= lo) & (rho < hi)) for lo, hi in RANGE_BINS]
    parts += [(f"{k} other segments within 1 m", near == k) for k in (0, 1)]
    parts += [(">= 2 other segments within 1 m", near >= 2)]
    for what, k in parts:
        if k.any():
            share, med = np.mean(sc[k] >= threshold), np.median(sc[k])
            out.append(
                f"  {what:32s} n {int(k.sum()):5d}  >= {threshold:g} {share:.3f}  median {med:.3f}"
            )
    return out


def _feature_table(groups: dict[str, list]) -> list[str]:
    mats = {
        g: np.array([r[2] for r in rows if r[2] is not None and 1.0 <= r[0] < 3.0])
        for g, rows in groups.items()
    }
    out = ["median features of the legs at 1-3 m: " + " | ".join(groups)]
    for j, n in enumerate(FEATURES):
        vals = "".join(
            f"{np.median(m[:, j]):10.4f}" if len(m) else "       nan" for m in mats.values()
        )
        out.append(f"  {n:28s}{vals}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="", help="a model file (default: the shipped one)")
    p.add_argument("--scenario", action="append", help=f"default: {', '.join(SCENARIOS)}")
    args = p.parse_args(argv)
    s = msgspec.structs.replace(LearnedSettings(), model_path=args.model)
    det = RandomTreesLegDetector(s)
    groups = {"real": real_rows(det)}
    for name in args.scenario or SCENARIOS:
        groups[name] = leg_rows(det, name)
    lines = []
    for label, rows in groups.items():
        lines += _summary(label, rows, s.threshold)
    lines += _feature_table(groups)
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
