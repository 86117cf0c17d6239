"""The real leg_tracker bags (../shared/data/leg_tracker): pairing, and floors on the figures.

Skipped when the data or the ``rosbags`` package is absent. The floors sit below the measured
figures (docs/laser_legs.md) so that a regression shows, not noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from followbot.research.legs_evaluate import VARIANTS, build
from followbot.research.realdata import data_dir, read_negative, read_positive, score
from followbot.services.laser_legs import make_detector

pytest.importorskip("rosbags", reason="rosbags is needed to read the ROS 1 bags")
if not (data_dir() / "positive_6_extracted.bag").is_file():
    pytest.skip(
        f"leg_tracker data absent at {data_dir()} (expected ../shared/data/leg_tracker "
        "relative to the repository root, or $FOLLOWBOT_LEG_DATA)",
        allow_module_level=True,
    )


def test_labels_pair_one_to_one_and_lie_on_scan_points():
    items = read_positive("positive_6")
    assert len(items) == 187
    for it in items[::10]:
        r = it.scan.ranges_m().astype(np.float64)
        a = it.scan.angles_rad()
        ok = np.isfinite(r)
        x, y = r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])
        for lx, ly in it.legs_xy:
            # labels are in the laser frame: a scan point within a leg radius
            assert np.min(np.hypot(x - lx, y - ly)) < 0.15
        assert it.scan.frame_id == "rear_laser"


def test_negative_topics():
    for topic in ("/left_scan", "/rear_scan", "/right_scan"):
        scans = read_negative(topic)
        assert len(scans) > 400
        assert scans[0].ranges.shape[0] > 700


def test_thesis_figures_held_out():
    pos = [s for n in ("positive_6", "positive_7") for s in read_positive(n)]
    neg = [s for t in ("/rear_scan", "/right_scan") for s in read_negative(t)]
    sc = score(make_detector("thesis"), pos, neg)
    assert sc.recall_near > 0.7
    assert sc.false_candidates_per_scan < 3.0


def test_learned_figures_held_out():
    # the shipped model never saw these bags (train.py reads only the training split)
    pos = [s for n in ("positive_6", "positive_7") for s in read_positive(n)]
    neg = [s for t in ("/rear_scan", "/right_scan") for s in read_negative(t)]
    # as the node runs it: behind the robot-body filter; measured 0.985 recall at 0.73 false
    # persons/scan with background_penalty 0.15 (0.47 at the cross-validated 0.3, which lost a
    # person standing still: docs/laser_legs.md); the tracker's evidence initiator publishes
    # none of them as people (docs/benchmark.md)
    sc = score(build("learned"), pos, neg)
    assert sc.recall > 0.95
    assert sc.false_candidates_per_scan < 0.85
    # the earlier background and operating point: measured 0.983 at 0.87
    sc = score(build("learned_maxrecall"), pos, neg)
    assert sc.recall > 0.95
    assert sc.false_candidates_per_scan < 1.1
    # the detector alone (static background and temporal confirmation, all chosen by
    # cross-validation), without the body filter: measured 0.985 at 0.49 (penalty 0.3)
    # since segments cut by the edge of the view are left out (before: 0.972 at 1.78, most of
    # the difference pieces of the rear and right lasers' robot body at the ends of their view)
    sc = score(make_detector("learned"), pos, neg)
    assert sc.recall > 0.95
    assert sc.false_candidates_per_scan < 0.85
    # without the tracks, at the thresholds chosen without them: measured 0.930 at 1.23
    sc = score(make_detector(*VARIANTS["learned_notrack"]), pos, neg)
    assert sc.recall > 0.90
    assert sc.false_candidates_per_scan < 1.4
    # without either, at the thresholds chosen without them: measured 0.884 at 0.97
    sc = score(make_detector(*VARIANTS["learned_nobg"]), pos, neg)
    assert sc.recall > 0.85
    assert sc.false_candidates_per_scan < 1.2


def test_learned_background_is_reset_between_scorings():
    # score() resets the stateful detector: the same data gives the same figures twice
    pos = list(read_positive("positive_2"))
    neg = list(read_negative("/left_scan"))[:60]
    det = make_detector("learned")
    a, b = score(det, pos, neg), score(det, pos, neg)
    assert (a.found_legs, a.false_candidates) == (b.found_legs, b.false_candidates)


def test_the_robot_body_is_found_at_the_ends_of_every_laser():
    from followbot.services.laser_legs.self_filter import RobotBodyFilter

    for topic in ("/left_scan", "/rear_scan", "/right_scan"):
        scans = read_negative(topic)
        f = RobotBodyFilter()
        masks = np.array([f.update(s) for s in scans])
        body = masks[len(scans) // 2 :].mean(axis=0) > 0.5  # once learned, most of the time
        n = body.shape[0]
        assert body.sum() >= 10, topic
        # the body is where the field of view ends (the scanners see 270 deg, the robot behind)
        idx = np.flatnonzero(body)
        assert np.all((idx < 40) | (idx >= n - 40)), (topic, idx)
        ranges = np.array([s.ranges.numpy() for s in scans[len(scans) // 2 :]])
        assert np.nanmedian(ranges[:, body]) < 1.0
