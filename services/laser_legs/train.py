"""Train the ``learned`` leg classifier: ``python -m followbot.services.laser_legs.train``.

Reproducible (fixed seeds, fixed data split); writes the model shipped with the package,
``services/laser_legs/models/learned_rtrees.yml.gz``, and prints the chosen threshold.

Training data (issue 4's split; the held-out data is never read here):

* real, leg_tracker bags: positive_1..4 — segments within 0.15 m of a labelled leg are legs,
  segments farther than ``--far-negatives-m`` (1 m) from every label are non-legs (those in
  between are left out: a person's other parts, or unlabelled legs);
  negative_2's ``/left_scan`` — every segment is a non-leg;
* simulator: the built-in scenarios with people, ``--sim-scans`` scans each — segments within
  0.15 m of a true leg centre are legs, those farther than 0.4 m from every leg are non-legs.

The vote threshold is chosen on a validation split *inside* the training data (train on
positive_1..3 and the first two thirds of /left_scan plus the simulator; validate on
positive_4 and the last third of /left_scan): the lowest threshold whose validation false
persons per scan stay within ``--max-false-per-scan``. The final model is then trained on all
the training data.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from .core import pair_legs
from .detectors.learned import (
    FEATURES,
    LearnedSettings,
    default_model_path,
    save_model,
    segment_features,
    segments,
    vote_share,
)
from .realdata import (
    MATCH_RADIUS_M,
    TRAIN_NEGATIVE_TOPICS,
    TRAIN_POSITIVES,
    read_negative,
    read_positive,
)

log = logging.getLogger(__name__)

SIM_SCENARIOS = (
    "thesis_5_2_1_arc",
    "thesis_5_2_2_straight",
    "thesis_5_2_4_two_people",
    "door_corner",
    "livingston_box_occlusion",
)


def _features(scan, s: LearnedSettings):
    st, en, x, y, r, valid = segments(scan, s.cluster_gap_m, s.min_points, s.max_width_m)
    f = segment_features(st, en, x, y, r, valid)
    cx = np.array([x[a : b + 1].mean() for a, b in zip(st, en, strict=True)])
    cy = np.array([y[a : b + 1].mean() for a, b in zip(st, en, strict=True)])
    return f, cx, cy


def _nearest(cx, cy, pts: np.ndarray) -> np.ndarray:
    if pts.shape[0] == 0 or cx.shape[0] == 0:
        return np.full(cx.shape[0], np.inf)
    return np.hypot(cx[:, None] - pts[None, :, 0], cy[:, None] - pts[None, :, 1]).min(axis=1)


def real_positive(names, s: LearnedSettings, far_negatives_m: float | None = None):
    """Legs of the labelled bags; with ``far_negatives_m``, also segments farther than that
    from every label as non-legs."""
    X, Y = [], []
    for name in names:
        for item in read_positive(name):
            f, cx, cy = _features(item.scan, s)
            d = _nearest(cx, cy, item.legs_xy)
            X.append(f[d <= MATCH_RADIUS_M])
            Y.append(np.ones(int((d <= MATCH_RADIUS_M).sum()), np.int32))
            if far_negatives_m is not None:
                far = d > far_negatives_m
                X.append(f[far])
                Y.append(np.zeros(int(far.sum()), np.int32))
    return X, Y


def real_negative(scans, s: LearnedSettings):
    X, Y = [], []
    for scan in scans:
        f, _, _ = _features(scan, s)
        X.append(f)
        Y.append(np.zeros(f.shape[0], np.int32))
    return X, Y


def simulated(n_scans: int, s: LearnedSettings, seed: int = 0):
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation

    X, Y = [], []
    for k, name in enumerate(SIM_SCENARIOS):
        sc = load_builtin(name)
        sim = Simulation(sc, seed=seed + k)
        period = round(1e9 / sc.laser.rate_hz)
        steps = max(1, int(sc.duration_s * sc.laser.rate_hz) // max(n_scans, 1))
        for i in range(n_scans):
            sim.advance_to(i * steps * period)
            scan = sim.scan()
            truth = sim.truth()
            legs = np.array(
                [p.legs_robot_m for p in truth.people if len(p.legs_robot_m) == 4]
            ).reshape(-1, 2)
            legs[:, 0] -= sc.laser.mount_x_m
            f, cx, cy = _features(scan, s)
            d = _nearest(cx, cy, legs)
            pos, neg = d <= MATCH_RADIUS_M, d > 0.4
            X += [f[pos], f[neg]]
            Y += [np.ones(int(pos.sum()), np.int32), np.zeros(int(neg.sum()), np.int32)]
    return X, Y


def fit(X: np.ndarray, Y: np.ndarray, trees: int, depth: int, seed: int):
    import cv2

    cv2.setRNGSeed(seed)
    m = cv2.ml.RTrees_create()
    m.setMaxDepth(depth)
    m.setMinSampleCount(5)
    m.setCalculateVarImportance(False)
    m.setActiveVarCount(0)  # sqrt(features)
    m.setTermCriteria((cv2.TERM_CRITERIA_MAX_ITER, trees, 0))
    m.train(np.ascontiguousarray(X, np.float32), cv2.ml.ROW_SAMPLE, Y.astype(np.int32))
    return m


def false_persons_per_scan(model, scans, s: LearnedSettings, threshold: float) -> float:
    total = 0
    for scan in scans:
        f, cx, cy = _features(scan, s)
        if f.shape[0] == 0:
            continue
        keep = vote_share(model, f) >= threshold
        total += len(pair_legs(cx[keep].tolist(), cy[keep].tolist(), s.pair_distance_m))
    return total / max(len(scans), 1)


def recall(model, items, s: LearnedSettings, threshold: float) -> float:
    found = total = 0
    for item in items:
        f, cx, cy = _features(item.scan, s)
        total += item.legs_xy.shape[0]
        if f.shape[0] == 0:
            continue
        keep = vote_share(model, f) >= threshold
        if keep.any():
            pts = np.column_stack([cx[keep], cy[keep]])
            found += int((_nearest(item.legs_xy[:, 0], item.legs_xy[:, 1], pts) <= 0.15).sum())
    return found / max(total, 1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--output", type=Path, default=default_model_path())
    p.add_argument("--sim-scans", type=int, default=300, help="scans per simulator scenario")
    p.add_argument("--trees", type=int, default=40)
    p.add_argument("--depth", type=int, default=12)
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--max-false-per-scan", type=float, default=0.5)
    p.add_argument(
        "--far-negatives-m",
        type=float,
        default=1.0,
        help="also use segments of the labelled bags this far from every label as non-legs",
    )
    args = p.parse_args(argv)
    s = LearnedSettings()
    neg_scans = [sc for t in TRAIN_NEGATIVE_TOPICS for sc in read_negative(t)]
    cut = 2 * len(neg_scans) // 3
    sim = simulated(args.sim_scans, s, args.seed) if args.sim_scans else ([], [])
    # 1. validation inside the training split: pick the threshold
    Xp, Yp = real_positive(TRAIN_POSITIVES[:-1], s, args.far_negatives_m)
    Xn, Yn = real_negative(neg_scans[:cut], s)
    X = np.vstack([*Xp, *Xn, *sim[0]])
    Y = np.concatenate([*Yp, *Yn, *sim[1]])
    log.info("validation fit: %d segments (%d legs)", len(Y), int(Y.sum()))
    model = fit(X, Y, args.trees, args.depth, args.seed)
    val_pos = read_positive(TRAIN_POSITIVES[-1])
    val_neg = neg_scans[cut:]
    threshold = 0.5
    for t in np.arange(0.2, 0.95, 0.05):
        fp = false_persons_per_scan(model, val_neg, s, float(t))
        rc = recall(model, val_pos, s, float(t))
        sys.stdout.write(f"threshold {t:.2f}: validation recall {rc:.3f}, false/scan {fp:.2f}\n")
        if fp <= args.max_false_per_scan:
            threshold = round(float(t), 2)
            break
    # 2. the final model on all the training data
    Xp, Yp = real_positive(TRAIN_POSITIVES, s, args.far_negatives_m)
    Xn, Yn = real_negative(neg_scans, s)
    X = np.vstack([*Xp, *Xn, *sim[0]])
    Y = np.concatenate([*Yp, *Yn, *sim[1]])
    model = fit(X, Y, args.trees, args.depth, args.seed)
    save_model(model, args.output)
    sys.stdout.write(
        f"trained on {len(Y)} segments ({int(Y.sum())} legs), features {', '.join(FEATURES)}\n"
        f"wrote {args.output}; threshold {threshold} (LearnedSettings.threshold)\n"
    )
    return 0


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    raise SystemExit(main())
