"""The histograms on real footage: OpenCV's pedestrian clip vtest.avi (opencv-doc)."""

from __future__ import annotations

import pytest

from followbot.research.vision_evaluate import evaluate_vtest

from .helpers import HOW, opencv_sample


def test_same_pedestrian_is_nearer_than_other_pedestrians_on_vtest():
    path = opencv_sample("vtest.avi")
    if path is None:
        pytest.skip(f"opencv-doc's vtest.avi {HOW}")
    r = evaluate_vtest(str(path), max_frames=120)
    assert r["frames"] == 120 and r["boxes"] > 100
    assert r["same_pairs"] > 50 and r["cross_pairs"] > 50
    same_p50 = r["same_distance_p50_p90"][0]
    cross_p50 = r["cross_distance_p10_p50"][1]
    assert 0.0 < same_p50 < cross_p50
    assert r["same_below_cross_median"] > 0.9
