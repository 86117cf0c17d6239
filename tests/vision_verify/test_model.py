"""Target model construction (thesis 3.3, 4.2) and model files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import Candidate, Leg, PersonCandidates
from followbot.services.vision_verify.core import Camera, Model
from followbot.services.vision_verify.model import (
    build_model,
    load_model,
    motion_rect,
    moving_candidates,
    recentre,
    save_model,
    smooth_grey,
)
from followbot.services.vision_verify.verifiers.histogram import HistogramVerifier

from .helpers import acquired_scene


def test_smoothing_kernel_keeps_flat_images_and_spreads_a_dot():
    flat = np.full((20, 20), 100, np.uint8)
    np.testing.assert_allclose(smooth_grey(flat), 100.0)
    dot = np.zeros((9, 9), np.uint8)
    dot[4, 4] = 160
    s = smooth_grey(dot)
    # separable [0.25 0.5 0.25]: centre 0.25, edge neighbours 0.125, corners 0.0625
    assert s[4, 4] == pytest.approx(40) and s[4, 5] == pytest.approx(20)
    assert s[3, 3] == pytest.approx(10) and s.sum() == pytest.approx(160)


def test_motion_rectangle_bounds_both_positions_and_ignores_small_changes():
    a = np.full((240, 320, 3), 60, np.uint8)
    b = a.copy()
    a[40:200, 100:140] = 250
    b[40:200, 110:150] = 250  # the block moved 10 px right
    b[10:12, 300:302] = 120  # a small, weak change: 60 -> 120 (< 80 after smoothing)
    rect, n = motion_rect(smooth_grey(a), smooth_grey(b))
    assert n > 0
    x0, y0, x1, y1 = rect
    assert 99 <= x0 <= 101 and 149 <= x1 <= 151  # left edge of a .. right edge of b
    assert y0 >= 38 and y1 <= 202
    rect2, n2 = motion_rect(smooth_grey(a), smooth_grey(a))
    assert rect2 is None and n2 == 0


def test_recentre_puts_the_rectangle_on_the_centre_line():
    assert recentre((10, 100, 50, 240), 320, 240, 120.0) == (10, 50, 50, 190)
    assert recentre((10, 0, 50, 240), 320, 240, 120.0) == (10, 0, 50, 240)


def _cands(spans):
    cs = [
        Candidate(
            x_m=1.0 + i,
            y_m=0.0,
            range_m=1.0 + i,
            bearing_rad=0.0,
            legs=[Leg(x_m=1.0 + i, y_m=0.0, first_beam=a, last_beam=b)],
        )
        for i, (a, b) in enumerate(spans)
    ]
    return PersonCandidates(stamp_ns=1, n_beams=100, candidates=cs)


def test_laser_difference_marks_the_candidate_whose_legs_moved():
    ref = np.full(100, 3.0)
    cur = ref.copy()
    cur[42:46] -= 0.05  # 50 mm change on candidate 1's leg (beams 40..48)
    cur[10] += 0.02  # 20 mm: noise, below 30 mm
    cur[80] = np.nan  # a lost return never counts
    cands = _cands([(8, 14), (40, 48), (78, 84)])
    assert moving_candidates(ref, cur, cands, 0.03, 2) == [1]
    cur[11:13] += 0.05  # now candidate 0 moved as well
    assert moving_candidates(ref, cur, cands, 0.03, 2) == [0, 1]
    assert moving_candidates(ref, ref, cands) == []
    assert moving_candidates(ref, cur[:50], cands) == []  # scans of different lengths


def test_builder_learns_the_target_when_it_moves_alone_in_the_simulator():
    """thesis_5_2_4: the target starts walking at 3 s, the bystander at 4 s."""
    camera, acq, _ = acquired_scene()
    assert acq is not None
    assert 3.0 <= acq.stamp_ns / 1e9 < 4.0
    assert math.hypot(acq.x_m - 1.65, acq.y_m - 0.0) < 0.3  # the target, ~1.6 m ahead
    x0, y0, x1, y1 = acq.rect
    u = camera.column(acq.x_m, acq.y_m)
    assert x0 <= u <= x1
    assert (x1 - x0) * (y1 - y0) >= 0.4 * 320 * 240
    assert (y0 + y1) / 2 == pytest.approx(120, abs=1)


def test_model_file_round_trip_and_bad_files(tmp_path):
    camera, acq, _ = acquired_scene()
    model = build_model(HistogramVerifier(), camera, acq, 7)
    assert model.features["colour_hs"].sum() == pytest.approx(1.0, abs=1e-5)
    assert model.features["edge_orientation"].sum() == pytest.approx(1.0, abs=1e-5)
    path = tmp_path / "models" / "target.model"
    save_model(path, model.to_message())
    back = Model.from_message(load_model(path), camera)
    assert back.model_id == 7 and back.depth_m == pytest.approx(model.depth_m)
    np.testing.assert_array_equal(back.features["colour_hs"], model.features["colour_hs"])
    (tmp_path / "junk").write_bytes(b"\x00not a model")
    with pytest.raises(ValueError, match="not a target model"):
        load_model(tmp_path / "junk")
    with pytest.raises(ValueError, match="cannot read"):
        load_model(tmp_path / "missing")


def test_model_learnt_with_the_camera_panned_keeps_its_depth():
    camera = Camera()
    msg = Model(
        model_id=1,
        verifier="histogram",
        x_m=1.0,
        y_m=1.0,
        depth_m=math.sqrt(2),
        rect_w_px=100,
        rect_h_px=200,
        image_width=320,
        image_height=240,
        features={},
        pan_rad=math.pi / 4,
    ).to_message()
    assert Model.from_message(msg, camera).depth_m == pytest.approx(math.sqrt(2))
    behind = Model(
        model_id=1,
        verifier="histogram",
        x_m=-1.0,
        y_m=0.0,
        depth_m=1.0,
        rect_w_px=100,
        rect_h_px=200,
        image_width=320,
        image_height=240,
        features={},
    ).to_message()
    with pytest.raises(ValueError, match="not in front"):
        Model.from_message(behind, camera)
