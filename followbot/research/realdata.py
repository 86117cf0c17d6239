"""The real laser data of the leg_tracker project (Angus Leigh, BSD-3-Clause), read in place.

The bags live outside the repository, in ``../shared/data/leg_tracker`` relative to the
repository root (override with ``FOLLOWBOT_LEG_DATA``); nothing is copied. They are ROS 1 bags
read with the ``rosbags`` package (pure Python, no ROS needed):

* ``positive_<k>_extracted.bag``: ``/training_scan`` (sensor_msgs/LaserScan) and, for every
  scan, the hand-labelled leg positions on ``/leg_cluster_positions`` (geometry_msgs/PoseArray).
  The labels carry the scan's ``frame_id`` (``right_laser`` / ``rear_laser``) and lie within about
  1 cm of the scan's points, so they are in the laser frame, as our detectors' output. Their
  header stamp is 0: each label message is recorded just before its scan (0.01-0.12 ms earlier
  in bag time) and the two topics have equal counts, so a scan pairs with the label message of
  nearest bag time (checked to be one-to-one).
* ``negative_2.bag``: scans of a cluttered room with nobody in it on ``/left_scan``,
  ``/rear_scan`` and ``/right_scan``: every person candidate there is false.

Issue 4's split: train on positive_1..4 and negative_2's /left_scan; score on positive_6,
positive_7 and negative_2's /rear_scan and /right_scan.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Sequence
from functools import lru_cache
from pathlib import Path

import msgspec
import numpy as np

from followbot.schemas import LaserScan, PersonCandidates
from followbot.services.laser_legs.core import LegDetector

__all__ = [
    "HELD_OUT_NEGATIVE_TOPICS",
    "HELD_OUT_POSITIVES",
    "LabelledScan",
    "Score",
    "data_dir",
    "detected_legs",
    "read_negative",
    "read_positive",
    "score",
    "to_laser_scan",
]

POSITIVES = ("positive_1", "positive_2", "positive_3", "positive_4", "positive_6", "positive_7")
TRAIN_POSITIVES = ("positive_1", "positive_2", "positive_3", "positive_4")
HELD_OUT_POSITIVES = ("positive_6", "positive_7")
NEGATIVE_TOPICS = ("/left_scan", "/rear_scan", "/right_scan")
TRAIN_NEGATIVE_TOPICS = ("/left_scan",)
HELD_OUT_NEGATIVE_TOPICS = ("/rear_scan", "/right_scan")

#: A labelled leg is found when a detected leg lies within this distance (issue 4).
MATCH_RADIUS_M = 0.15


def data_dir() -> Path:
    """Where the bags are: $FOLLOWBOT_LEG_DATA, else <repo>/../shared/data/leg_tracker."""
    env = os.environ.get("FOLLOWBOT_LEG_DATA")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    return repo.parent / "shared" / "data" / "leg_tracker"


def to_laser_scan(msg) -> LaserScan:
    """A sensor_msgs/LaserScan (as deserialised by rosbags) as our wire LaserScan."""
    ranges = np.asarray(msg.ranges, dtype=np.float32)
    inten = np.asarray(msg.intensities, dtype=np.float32)
    stamp = msg.header.stamp
    return LaserScan.from_ranges(
        ranges,
        stamp_ns=int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec),
        angle_min_rad=float(msg.angle_min),
        angle_increment_rad=float(msg.angle_increment),
        range_min_m=float(msg.range_min),
        range_max_m=float(msg.range_max),
        intensities=inten if inten.shape == ranges.shape else None,
        frame_id=msg.header.frame_id,
        seq=int(msg.header.seq),
        scan_time_s=max(float(msg.scan_time), 0.0),
    )


class LabelledScan(msgspec.Struct, frozen=True):
    scan: LaserScan
    legs_xy: np.ndarray
    """(k, 2) labelled leg positions in the scan's frame (m)."""


def _reader(path: Path):
    from rosbags.highlevel import AnyReader  # lazy: only evaluation needs rosbags

    return AnyReader([path])


@lru_cache(maxsize=16)
def read_positive(name: str, directory: Path | None = None) -> tuple[LabelledScan, ...]:
    """Scans of ``<name>_extracted.bag`` with their labelled legs, paired by bag time."""
    path = (directory or data_dir()) / f"{name}_extracted.bag"
    scans: list[tuple[int, LaserScan]] = []
    labels: list[tuple[int, np.ndarray]] = []
    with _reader(path) as reader:
        cons = [
            c for c in reader.connections if c.topic in ("/training_scan", "/leg_cluster_positions")
        ]
        for con, t, raw in reader.messages(connections=cons):
            msg = reader.deserialize(raw, con.msgtype)
            if con.topic == "/training_scan":
                scans.append((t, to_laser_scan(msg)))
            else:
                xy = np.array([[p.position.x, p.position.y] for p in msg.poses], dtype=np.float64)
                labels.append((t, xy.reshape(-1, 2)))
    if not scans or not labels:
        return ()
    lt = np.array([t for t, _ in labels])
    out = []
    used = set()
    for t, scan in scans:
        j = int(np.argmin(np.abs(lt - t)))
        if j in used:  # one label message per scan; never reuse one
            continue
        used.add(j)
        out.append(LabelledScan(scan, labels[j][1]))
    return tuple(out)


@lru_cache(maxsize=8)
def read_negative(topic: str, directory: Path | None = None) -> tuple[LaserScan, ...]:
    """Scans of ``negative_2.bag`` on ``topic`` (nobody in them)."""
    path = (directory or data_dir()) / "negative_2.bag"
    with _reader(path) as reader:
        cons = [c for c in reader.connections if c.topic == topic]
        return tuple(
            to_laser_scan(reader.deserialize(raw, con.msgtype))
            for con, _, raw in reader.messages(connections=cons)
        )


def detected_legs(result: PersonCandidates) -> np.ndarray:
    """(k, 2) positions of every detected leg (a leg-less candidate counts as one leg)."""
    pts = [(leg.x_m, leg.y_m) for c in result.candidates for leg in (c.legs or [c])]
    return np.array(pts, dtype=np.float64).reshape(-1, 2)


class Score(msgspec.Struct, kw_only=True):
    """Real-data figures of one detector (issue 4 "Must show")."""

    detector: str
    labelled_legs: int = 0
    found_legs: int = 0
    labelled_legs_near: int = 0
    """Labelled legs within ``near_m`` of the laser."""
    found_legs_near: int = 0
    positive_scans: int = 0
    negative_scans: int = 0
    false_candidates: int = 0
    false_legs: int = 0
    time_us: list[float] = []

    @property
    def recall(self) -> float:
        return self.found_legs / self.labelled_legs if self.labelled_legs else float("nan")

    @property
    def recall_near(self) -> float:
        n = self.labelled_legs_near
        return self.found_legs_near / n if n else float("nan")

    @property
    def false_candidates_per_scan(self) -> float:
        n = self.negative_scans
        return self.false_candidates / n if n else float("nan")

    @property
    def false_legs_per_scan(self) -> float:
        n = self.negative_scans
        return self.false_legs / n if n else float("nan")

    @property
    def median_time_us(self) -> float:
        return float(np.median(self.time_us)) if self.time_us else float("nan")


def score(
    detector: LegDetector,
    positives: Iterable[LabelledScan],
    negatives: Sequence[LaserScan],
    *,
    name: str | None = None,
    near_m: float = 3.5,
) -> Score:
    """Leg recall on ``positives`` and false person candidates per scan on ``negatives``.

    Scans are fed in order (positives, then negatives) to the one detector, as a live node
    would; a stateful detector (``learned`` with its static background) is reset first and
    starts afresh by itself where a stream changes (frame, geometry, stamps). It never sees
    the labels."""
    reset = getattr(detector, "reset", None)
    if callable(reset):
        reset()
    out = Score(detector=name or detector.name)
    clock = time.perf_counter
    for item in positives:
        t0 = clock()
        result = detector.detect(item.scan)
        out.time_us.append((clock() - t0) * 1e6)
        found = detected_legs(result)
        labels = item.legs_xy
        out.positive_scans += 1
        out.labelled_legs += labels.shape[0]
        near = np.hypot(labels[:, 0], labels[:, 1]) <= near_m
        out.labelled_legs_near += int(near.sum())
        if found.shape[0] and labels.shape[0]:
            d = np.hypot(
                labels[:, None, 0] - found[None, :, 0], labels[:, None, 1] - found[None, :, 1]
            )
            hit = d.min(axis=1) <= MATCH_RADIUS_M
            out.found_legs += int(hit.sum())
            out.found_legs_near += int((hit & near).sum())
    for scan in negatives:
        t0 = clock()
        result = detector.detect(scan)
        out.time_us.append((clock() - t0) * 1e6)
        out.negative_scans += 1
        out.false_candidates += len(result.candidates)
        out.false_legs += detected_legs(result).shape[0]
    return out
