"""Leg detectors on other scanners than the leg_tracker bags: ``python -m
followbot.research.legs_scanners --detectors learned thesis``.

* legs360 (``legs360/``): a still 360 deg scanner, 720 beams at 0.5 deg, one walker with
  labelled legs. Leg recall (a detected leg within 0.15 m of a labelled one, as on the
  leg_tracker bags) and false candidates per scan (candidates none of whose legs lies within
  0.5 m of a labelled leg: the walker is the only person in the room);
* CARMEN (``carmen/*.log.gz``): eight office runs, 180 deg at 0.5 or 1 deg, robot moving, nobody
  walking: every candidate is false (the data's README). False candidates per scan, per log and
  pooled over all the scans;
* ``--odometry``: the CARMEN scans are given to the detectors with the laser's pose from the
  logs' odometry (each laser record's own odometry composed with the laser's mount from
  ROBOTLASER records, else the base's origin), as the laser_legs node gives it from
  ``sensors/odom``: ``learned`` then registers its background by odometry instead of ICP;
* ``--train-split``: the leg_tracker training split (positive_1..4, negative_2 ``/left_scan``),
  for choices made without the held-out split (the shipped forest was fitted on these scans, so
  its recall there is in-sample).

Every detector runs behind the robot-body filter, as the laser_legs node and ``followbot
benchmark`` build it, each recording fed in order to a freshly reset detector. Needs
``rosbags`` and the data folder (``--data``, default ``<repo>/../shared/data``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from followbot.research.realdata import (
    MATCH_RADIUS_M,
    TRAIN_NEGATIVE_TOPICS,
    TRAIN_POSITIVES,
    LabelledScan,
    detected_legs,
    read_negative,
    read_positive,
    score,
    to_laser_scan,
)
from followbot.schemas import LaserScan
from followbot.services.common.geometry import Pose
from followbot.services.laser_legs.detectors import make_detector
from followbot.services.laser_legs.self_filter import SelfFilteredDetector

#: A legs360 candidate with no leg this near a labelled leg is false (m).
LEGS360_FALSE_M = 0.5


def data_root() -> Path:
    return Path(__file__).resolve().parents[2].parent / "shared" / "data"


def read_legs360(folder: Path) -> list[LabelledScan]:
    """legs360's scans with their labelled legs (an unlabelled scan gets none)."""
    from rosbags.highlevel import AnyReader

    labels: dict[int, list[tuple[float, float]]] = {}
    with (folder / "legs360_labels.csv").open(newline="") as f:
        for row in csv.DictReader(f):
            labels.setdefault(int(row["stamp_ns"]), []).append(
                (float(row["x_m"]), float(row["y_m"]))
            )
    out = []
    with AnyReader([folder / "legs360.bag"]) as reader:
        cons = [c for c in reader.connections if c.topic == "/scan"]
        for con, _, raw in reader.messages(connections=cons):
            scan = to_laser_scan(reader.deserialize(raw, con.msgtype))
            xy = np.array(labels.get(int(scan.stamp_ns), []), dtype=np.float64).reshape(-1, 2)
            out.append(LabelledScan(scan, xy))
    return out


def read_carmen(path: Path, odometry: bool = False) -> list[tuple[LaserScan, Pose | None]]:
    """The log's scans, each with the laser's odometry pose (``odometry``) or None."""
    import math

    from followbot.carmen import CarmenLog

    log = CarmenLog(path)
    source = next(s for s in ("ROBOTLASER1", "FLASER", "RAWLASER1") if s in log.contents)
    if not odometry or f"{source}/odom" not in log.contents:
        return [(m, None) for _, _, m in log.messages([source])]
    mx, my, myaw = log.laser_mount(source) or (0.0, 0.0, 0.0)
    out, odom = [], None
    for _, src, m in log.messages([source, f"{source}/odom"]):
        if src != source:  # a laser record's odometry comes just before its scan
            odom = m
            continue
        pose = None
        if odom is not None and odom.stamp_ns == m.stamp_ns:
            c, s = math.cos(odom.yaw_rad), math.sin(odom.yaw_rad)
            pose = (odom.x_m + c * mx - s * my, odom.y_m + s * mx + c * my, odom.yaw_rad + myaw)
        out.append((m, pose))
    return out


def build(name: str, overrides: dict | None):
    return SelfFilteredDetector(make_detector(name, overrides or None))


def legs360_figures(det, scans: Sequence[LabelledScan]) -> dict:
    det.reset()
    labelled = found = false = 0
    times = []
    for item in scans:
        t0 = time.perf_counter()
        result = det.detect(item.scan)
        times.append(time.perf_counter() - t0)
        labels = item.legs_xy
        labelled += labels.shape[0]
        got = detected_legs(result)
        if got.shape[0] and labels.shape[0]:
            d = np.hypot(labels[:, None, 0] - got[None, :, 0], labels[:, None, 1] - got[None, :, 1])
            found += int((d.min(axis=1) <= MATCH_RADIUS_M).sum())
        for c in result.candidates:
            pts = np.array([(leg.x_m, leg.y_m) for leg in (c.legs or [c])])
            if (
                labels.shape[0] == 0
                or np.hypot(
                    pts[:, None, 0] - labels[None, :, 0], pts[:, None, 1] - labels[None, :, 1]
                ).min()
                > LEGS360_FALSE_M
            ):
                false += 1
    return {
        "leg_recall": round(found / max(labelled, 1), 3),
        "false_candidates_per_scan": round(false / max(len(scans), 1), 3),
        "us_per_scan_p50": round(float(np.median(times)) * 1e6),
    }


def carmen_figures(det, logs: dict[str, list[tuple[LaserScan, Pose | None]]]) -> dict:
    out: dict = {}
    total = scans = 0
    for name, stream in logs.items():
        det.reset()
        n = sum(len(det.detect(s, None, pose).candidates) for s, pose in stream)
        out[name] = round(n / max(len(stream), 1), 3)
        total += n
        scans += len(stream)
    out["all"] = round(total / max(scans, 1), 3)
    return out


def train_split_figures(det, positives: Iterable, negatives: Sequence) -> dict:
    sc = score(det, positives, negatives)
    return {
        "leg_recall": round(sc.recall, 3),
        "false_candidates_per_scan": round(sc.false_candidates_per_scan, 3),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--detectors", nargs="+", default=["learned", "thesis"])
    p.add_argument("--set", default="{}", help="JSON detector settings overrides for all")
    p.add_argument("--data", type=Path, default=None)
    p.add_argument("--train-split", action="store_true")
    p.add_argument("--no-carmen", action="store_true")
    p.add_argument(
        "--odometry", action="store_true", help="CARMEN scans with the laser's odometry pose"
    )
    args = p.parse_args(argv)
    root = args.data or data_root()
    overrides = json.loads(args.set)
    l360 = read_legs360(root / "legs360")
    logs = {}
    if not args.no_carmen:
        for path in sorted((root / "carmen").glob("*.log.gz")):
            logs[path.name.split("-")[0]] = read_carmen(path, args.odometry)
    if args.train_split:
        tpos = [s for n in TRAIN_POSITIVES for s in read_positive(n)]
        tneg = [s for t in TRAIN_NEGATIVE_TOPICS for s in read_negative(t)]
    for name in args.detectors:
        det = build(name, overrides)
        row = {"detector": name, "legs360": legs360_figures(det, l360)}
        if logs:
            row["carmen_false_per_scan"] = carmen_figures(det, logs)
        if args.train_split:
            row["train_split"] = train_split_figures(det, tpos, tneg)
        sys.stdout.write(json.dumps(row) + "\n")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
