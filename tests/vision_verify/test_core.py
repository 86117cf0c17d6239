"""Histograms, Bhattacharyya distance, rectangle geometry and the choice (core.py)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from followbot.services.vision_verify.core import (
    COLOUR_BINS,
    EDGE_BINS,
    Camera,
    ImageFeatures,
    Model,
    View,
    adapt_features,
    bhattacharyya,
    blend,
    choose,
    colour_histogram,
    confident,
    covered_fraction,
    edge_histogram,
    horizon_covers,
    judge,
    occlude,
    project,
)


def patch(bgr, h=40, w=30):
    return np.full((h, w, 3), bgr, dtype=np.uint8)


# --------------------------------------------------------------------------- colour


def test_saturated_red_falls_in_hue_0_saturation_9_of_both_halves():
    hist = colour_histogram(patch((0, 0, 255)))  # BGR red: H 0, S 255, V 255
    assert hist.shape == (COLOUR_BINS,) and hist.dtype == np.float32
    want = np.zeros(COLOUR_BINS, np.float32)
    want[0 * 10 + 9] = 0.5  # upper half: HS bin (hue 0, sat 9)
    want[108 + 9] = 0.5  # lower half
    np.testing.assert_allclose(hist, want, atol=1e-6)


def test_dark_and_grey_pixels_go_to_brightness_bins():
    dark = colour_histogram(patch((30, 30, 30)))  # V = 30 < 51: brightness bin 30*8//256 = 0
    assert dark[100] == pytest.approx(0.5) and dark[208] == pytest.approx(0.5)
    grey = colour_histogram(patch((200, 200, 200)))  # S = 0 < 51, V = 200: bin 6
    assert grey[106] == pytest.approx(0.5) and grey[214] == pytest.approx(0.5)
    # a saturated but dark colour (V < 51) is brightness too, not colour
    dim_red = colour_histogram(patch((0, 0, 40)))
    assert dim_red[101] == pytest.approx(0.5) and dim_red[:100].sum() == 0  # V 40: bin 1


def test_upper_and_lower_halves_keep_spatial_layout():
    a = np.vstack([patch((0, 0, 255), 20), patch((255, 0, 0), 20)])  # red over blue
    b = np.vstack([patch((255, 0, 0), 20), patch((0, 0, 255), 20)])  # blue over red
    ha, hb = colour_histogram(a), colour_histogram(b)
    assert ha.sum() == pytest.approx(1.0) and hb.sum() == pytest.approx(1.0)
    assert bhattacharyya(ha, hb) > 0.99  # one histogram of the whole patch would say 0
    assert bhattacharyya(ha, colour_histogram(a.copy())) == pytest.approx(0.0, abs=1e-3)


def _reference_colour(bgr: np.ndarray) -> np.ndarray:
    """Thesis 4.2.1.2 written out with numpy, pixel by pixel rules (the spec, not the code)."""
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV).astype(np.int64)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    colour = (s >= 51) & (v >= 51)
    idx = np.where(colour, (h * 10 // 180) * 10 + (s * 10 // 256), 100 + v * 8 // 256)
    mid = bgr.shape[0] // 2
    out = []
    for part in (idx[:mid], idx[mid:]):
        c = np.bincount(part.ravel(), minlength=108).astype(np.float64)
        out.append(0.5 * c / c.sum())
    return np.concatenate(out)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 60), st.integers(1, 60), st.integers(0, 2**32 - 1))
def test_colour_histogram_matches_the_rule_on_random_patches(h, w, seed):
    bgr = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    np.testing.assert_allclose(colour_histogram(bgr), _reference_colour(bgr), atol=1e-5)


# --------------------------------------------------------------------------- edges


def test_vertical_step_edge_points_at_0_deg_horizontal_at_90():
    img = np.zeros((40, 40, 3), np.uint8)
    img[:, 20:] = 200  # dark left, bright right: Gx > 0, Gy = 0 -> 0 deg
    e = edge_histogram(img)
    assert e.shape == (EDGE_BINS,) and e[0] == pytest.approx(1.0)
    img = np.zeros((40, 40, 3), np.uint8)
    img[20:] = 200  # dark top, bright bottom: Gy > 0 -> 90 deg, bin 18
    assert edge_histogram(img)[18] == pytest.approx(1.0)
    img = np.zeros((40, 40, 3), np.uint8)
    img[:, :20] = 200  # bright left: 180 deg, bin 36
    assert edge_histogram(img)[36] == pytest.approx(1.0)


def test_flat_patch_has_no_edges_and_is_far_from_everything():
    e = edge_histogram(patch((90, 90, 90)))
    assert e.sum() == 0
    assert bhattacharyya(e, np.full(EDGE_BINS, 1 / EDGE_BINS, np.float32)) == 1.0


def test_weak_edges_below_0_4_of_the_strongest_are_ignored():
    img = np.zeros((40, 60, 3), np.uint8)
    img[:, 20:] = 30  # weak step (0 deg)
    img[:, 40:] = 255  # strong step (0 deg too) ...
    img[30:, :] = 0
    img[30:, 10:] = 255  # ... and a strong step in the bottom rows
    e = edge_histogram(img)
    # the weak 0->30 step is far below 0.4 of the 30->255 or 0->255 steps: only 0 deg and the
    # corners' diagonal edges of the strong steps vote
    weak = np.zeros((40, 60, 3), np.uint8)
    weak[:, 20:] = 30
    assert edge_histogram(weak)[0] == pytest.approx(1.0)
    assert e.sum() == pytest.approx(1.0)


# --------------------------------------------------------------------------- distance


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 300))
def test_bhattacharyya_equals_the_thesis_formula(seed, n):
    rng = np.random.default_rng(seed)
    p = rng.random(n).astype(np.float32)
    q = rng.random(n).astype(np.float32)
    p[rng.random(n) < 0.3] = 0
    p[0] += 0.01
    p /= p.sum()
    q /= q.sum()
    want = math.sqrt(max(0.0, 1.0 - float(np.sum(np.sqrt(p.astype(float) * q)))))
    assert bhattacharyya(p, q) == pytest.approx(want, abs=2e-3)


def test_bhattacharyya_bounds():
    p = np.array([1, 0, 0, 0], np.float32)
    q = np.array([0, 0.5, 0.5, 0], np.float32)
    assert bhattacharyya(p, p) == pytest.approx(0.0, abs=1e-4)
    assert bhattacharyya(p, q) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        bhattacharyya(p, np.ones(5, np.float32))


def test_rectangles_of_one_frame_equal_separate_patches_inside():
    """Whole-frame work shared by rectangles gives the same colour histogram as the patch
    alone (edges may differ by a pixel at the border, where the frame has real neighbours)."""
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), (9, 9), 3)
    frame = ImageFeatures(img)
    rect = (30, 10, 90, 100)
    np.testing.assert_allclose(frame.colour(rect), colour_histogram(img[10:100, 30:90]), atol=1e-6)
    assert bhattacharyya(frame.edges(rect), edge_histogram(img[10:100, 30:90])) < 0.2


# --------------------------------------------------------------------------- geometry


CAM = Camera()  # 320 x 240, 47.5 deg: f = 160 / tan(23.75 deg)


def test_focal_length_is_the_thesis_value():
    assert CAM.f == pytest.approx(160 / math.tan(math.radians(23.75)))
    assert 362 < CAM.f < 364


def test_candidate_ahead_lands_at_the_centre_with_scaled_size():
    (v,) = project(CAM, [[2.0, 0.0]], 0.0, 100, 200, 1.5)
    assert v.ok and v.u_px == pytest.approx(160.0)
    w, h = 100 * 1.5 / 2.0, 200 * 1.5 / 2.0  # eq. 3-20, 3-21: 75 x 150
    assert v.rect == (
        round(160 - w / 2),
        round(120 - h / 2),
        round(160 + w / 2),
        round(120 + h / 2),
    )


def test_candidate_to_the_left_and_panning_onto_it():
    x, y = 2.0, 0.5
    (v,) = project(CAM, [[x, y]], 0.0, 100, 200, 2.0)
    assert v.u_px == pytest.approx(160 - CAM.f * y / x)  # eq. 3-18: left of centre
    assert v.u_px < 160
    (v,) = project(CAM, [[x, y]], math.atan2(y, x), 100, 200, 2.0)  # pan onto it
    assert v.u_px == pytest.approx(160.0)
    assert v.depth_m == pytest.approx(math.hypot(x, y))
    # pan 30 deg left; candidate 10 deg right of the optical axis, 3 m away
    a = math.radians(30 - 10)
    (v,) = project(CAM, [[3 * math.cos(a), 3 * math.sin(a)]], math.radians(30), 100, 200, 2.0)
    assert v.u_px == pytest.approx(160 + CAM.f * math.tan(math.radians(10)))
    assert v.rect[2] - v.rect[0] == pytest.approx(
        100 * 2.0 / (3 * math.cos(math.radians(10))), abs=1
    )


def test_camera_offset_from_the_laser_is_removed():
    cam = Camera(offset_x_m=0.2, offset_y_m=0.1)
    (v,) = project(cam, [[2.2, 0.1]], 0.0, 100, 200, 1.0)
    assert v.depth_m == pytest.approx(2.0) and v.u_px == pytest.approx(160.0)


def test_matches_the_simulator_camera_convention():
    from followbot.services.sim.camera import CameraModel
    from followbot.services.sim.scenario import CameraSpec, WorldSpec
    from followbot.services.sim.world import StaticWorld

    sim_cam = CameraModel(
        CameraSpec(noise_std=0), StaticWorld.from_spec(WorldSpec()), np.random.default_rng(0)
    )
    for x, y, pan in [(2.0, 0.3, 0.0), (3.0, -1.0, -0.2), (1.5, 1.0, 0.6)]:
        (v,) = project(CAM, [[x, y]], pan, 50, 50, 1.0)
        cam_pose = sim_cam.camera_pose((0.0, 0.0, 0.0), pan)
        xc, yc = sim_cam.to_camera(cam_pose, np.array([x, y]))
        assert v.u_px == pytest.approx(sim_cam.column(xc, yc))


@pytest.mark.parametrize(
    ("xy", "pan", "status"),
    [
        ([-1.0, 0.0], 0.0, "behind"),
        ([0.0, 0.0], 0.0, "behind"),
        ([0.1, 0.0], 0.0, "behind"),  # nearer than min_depth_m
        ([2.0, 0.0], math.pi, "behind"),  # camera turned round
        ([2.0, 2.0], 0.0, "out_of_view"),  # 45 deg left, FOV +-23.75 deg
        ([2.0, -1.0], 0.0, "out_of_view"),
        ([0.31, 0.0], 0.0, "too_large"),  # almost at the lens: 3000 px wide
        ([150.0, 0.0], 0.0, "too_small"),  # far: 6 px wide
    ],
)
def test_candidates_not_judged(xy, pan, status):
    (v,) = project(CAM, [xy], pan, 300, 200, 3.0)
    assert v.status == status and v.rect is None and not v.ok


def test_non_finite_positions_are_invalid_not_errors():
    views = project(CAM, [[math.nan, 0.0], [math.inf, 1.0], [2.0, 0.0]], 0.0, 100, 100, 2.0)
    assert [v.status for v in views] == ["invalid", "invalid", "ok"]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)), max_size=12),
    st.floats(-7, 7),
    st.floats(1, 4096),
    st.floats(1, 4096),
    st.floats(0.3, 50),
)
def test_every_rectangle_lies_inside_the_image(xy, pan, w, h, depth):
    views = project(CAM, np.array(xy).reshape(-1, 2), pan, w, h, depth)
    assert len(views) == len(xy)
    for v in views:
        if v.ok:
            x0, y0, x1, y1 = v.rect
            assert 0 <= x0 < x1 <= 320 and 0 <= y0 < y1 <= 240
            assert x1 - x0 >= 8 and y1 - y0 >= 8
            assert v.depth_m >= CAM.min_depth_m and 0 <= v.u_px < 320


# --------------------------------------------------------------------------- choice, update


def test_choose_takes_the_smallest_and_the_threshold_can_refuse():
    assert choose([0.9, None, 0.4, 0.7], None) == 2
    assert choose([0.9, None, 0.4, 0.7], 0.5) == 2
    assert choose([0.9, None, 0.6, 0.7], 0.5) == -1
    assert choose([None, None], None) == -1
    assert choose([], 0.5) == -1


def test_confident_needs_closeness_and_a_margin():
    assert confident([0.2, 0.8], 0, 0.4, 0.2)
    assert not confident([0.2, 0.3], 0, 0.4, 0.2)  # a rival too close
    assert not confident([0.5, 1.5], 0, 0.4, 0.2)  # not close enough to the model
    assert not confident([0.5], -1, 0.4, 0.2)
    assert confident([0.1, None], 0, 0.4, 0.2)


def test_blend_moves_slowly_and_stays_normalised():
    m = np.array([1, 0, 0, 0], np.float32)
    s = np.array([0, 1, 0, 0], np.float32)
    out = blend(m, s, 0.05)
    np.testing.assert_allclose(out, [0.95, 0.05, 0, 0], atol=1e-6)
    feats = adapt_features({"a": m, "b": m}, {"a": s, "c": s}, 0.5)
    np.testing.assert_allclose(feats["a"], [0.5, 0.5, 0, 0])
    assert feats["b"] is m and "c" not in feats


def _view(i: int, depth: float, rect) -> View:
    return View(index=i, x_m=depth, y_m=0.0, depth_m=depth, rect=rect)


def test_a_candidate_keeps_only_the_columns_no_nearer_candidate_covers():
    near = _view(0, 1.0, (100, 0, 200, 240))
    half = _view(1, 2.0, (150, 40, 250, 200))  # its right half shows
    hidden = _view(2, 3.0, (120, 60, 180, 180))  # wholly behind the nearest
    occlude([half, hidden, near], 0.5)
    assert near.ok and near.rect == (100, 0, 200, 240) and near.projected is None
    assert half.ok and half.rect == (200, 40, 250, 200)
    assert half.projected == (150, 40, 250, 200)
    assert hidden.status == "occluded"


def test_a_candidate_behind_a_narrow_one_keeps_its_wider_side_or_is_occluded():
    post = _view(0, 1.0, (140, 0, 160, 240))
    wide = _view(1, 2.0, (100, 0, 200, 240))  # 40 px left of the post, 40 px right
    occlude([post, wide], 0.4)
    assert wide.ok and wide.rect == (100, 0, 140, 240)
    wide = _view(1, 2.0, (100, 0, 200, 240))
    occlude([post, wide], 0.5)  # 40 of 100 columns in one run: under half
    assert wide.status == "occluded"


def test_only_judged_candidates_hide_others():
    gone = _view(0, 1.0, (0, 0, 320, 240))
    gone.status = "too_large"
    far = _view(1, 2.0, (100, 0, 200, 240))
    occlude([gone, far], 0.5)
    assert far.ok and far.rect == (100, 0, 200, 240)


def _histogram_on_grey():
    """The histogram verifier, a grey image and a model of a red person learnt at 2 m."""
    from followbot.services.vision_verify.verifiers import make_verifier

    model = Model(
        model_id=1, verifier="histogram", x_m=2.0, y_m=0.0, depth_m=2.0, rect_w_px=80,
        rect_h_px=160, image_width=320, image_height=240,
        features={"colour_hs": colour_histogram(patch((0, 0, 200))),
                  "edge_orientation": np.full(EDGE_BINS, 1 / EDGE_BINS, np.float32)},
    )  # fmt: skip
    return make_verifier("histogram"), ImageFeatures(np.full((240, 320, 3), 90, np.uint8)), model


def test_judge_skips_the_candidate_behind_and_can_be_told_not_to():
    """Two candidates one behind the other: only the nearer one is judged by default."""
    v, frame, model = _histogram_on_grey()
    xy = np.array([[2.0, 0.0], [3.0, 0.05]])
    j = judge(v, frame, CAM, model, xy, 0.0, None)
    assert [w.status for w in j.views] == ["ok", "occluded"] and j.distances[1] is None
    j = judge(v, frame, CAM, model, xy, 0.0, None, min_visible_fraction=None)
    assert [w.status for w in j.views] == ["ok", "ok"] and j.distances[1] is not None


def _horizon(returns, far_m=np.inf):
    """A 360 x 1-degree horizon from -180 deg: ``far_m`` everywhere (inf: no return) but for
    each (bearing_deg, range_m) of ``returns``."""
    from followbot.schemas import Array, Horizon

    r = np.full(360, far_m, dtype=np.float32)
    for bearing, rng in returns:
        r[int(bearing + 180)] = rng
    return Horizon(
        angle_min_rad=-math.pi, increment_rad=math.radians(1.0), ranges=Array.from_numpy(r)
    )


def test_horizon_covers_widens_each_return_in_view_by_a_body():
    """A return 1 m ahead (bin [0, 1) deg) hides the columns of a 0.2 m half-width body at 1 m
    (plus its bin's half width); returns behind the camera, out of the image or missing (inf)
    hide nothing."""
    h = _horizon([(0.0, 1.0), (180.0 - 1, 1.0), (80.0, 1.0)])
    covers = horizon_covers(CAM, h, 0.0, 0.2)
    assert covers.shape == (1, 3)
    depth, u0, u1 = covers[0]
    centre = math.radians(0.5)
    assert depth == pytest.approx(math.cos(centre))
    half = 0.2 + 0.5 * math.radians(1.0)
    assert u0 == pytest.approx(CAM.column(depth, math.sin(centre) + half))
    assert u1 == pytest.approx(CAM.column(depth, math.sin(centre) - half))
    assert u0 < CAM.cx < u1
    # turned 80 deg, the camera sees the third return instead
    ((depth80, _, _),) = horizon_covers(CAM, h, math.radians(80.5), 0.2)
    assert depth80 == pytest.approx(1.0)
    # a pillar's face (30 neighbouring returns at 1 m, 0.52 m wide) is no leg: it hides nothing
    pillar = _horizon([(b, 1.0) for b in range(-15, 15)], far_m=6.0)
    assert horizon_covers(CAM, pillar, 0.0, 0.2).shape == (0, 3)
    # two legs 0.3 m apart in front of it are
    legs = _horizon([(b, 1.0) for b in range(-15, 15)] + [(-9, 0.6), (-8, 0.6), (8, 0.6)], 6.0)
    assert sorted(horizon_covers(CAM, legs, 0.0, 0.2)[:, 0].round(1).tolist()) == [0.6] * 3


def test_what_the_laser_saw_in_front_of_a_candidate_hides_it():
    """covers: a span more than margin_m nearer hides the columns it covers (here 70 of the
    candidate's 100: occluded at 0.5), one within the margin (the candidate's own legs) or
    behind it does not."""

    def cand():
        return _view(0, 2.0, (100, 0, 200, 240))

    v = cand()
    occlude([v], 0.5, covers=np.array([[1.0, 80.4, 169.6]]), margin_m=0.3)
    assert v.status == "occluded"
    v = cand()
    occlude([v], 0.5, covers=np.array([[1.0, 60.0, 130.0]]), margin_m=0.3)
    assert v.ok and v.rect == (130, 0, 200, 240)  # the columns left of 130 are the passer-by's
    for depth in (1.8, 2.5):
        v = cand()
        occlude([v], 0.5, covers=np.array([[depth, 80.0, 170.0]]), margin_m=0.3)
        assert v.ok and v.rect == (100, 0, 200, 240)


def test_judge_does_not_judge_a_target_behind_a_passer_by_the_detector_left_out():
    """crowd_ten's own seed at 37.44 s: the target's candidate at (1.57, 0.12); a passer-by's
    legs 1.2 m ahead, 0.1-0.35 m to the right, are no candidate (criterion 3). With the
    horizon the target is occluded (no judgement, so no rejection); without it, judged."""
    v, frame, model = _histogram_on_grey()
    xy = np.array([[1.57, 0.12]])
    legs = [(-16.0, 1.2), (-15.0, 1.2), (-5.0, 1.2), (-4.0, 1.2), (4.0, 1.55), (5.0, 1.6)]
    h = _horizon(legs, far_m=6.0)
    j = judge(v, frame, CAM, model, xy, 0.0, None, horizon=h, horizon_margin_m=0.3)
    assert j.views[0].status == "occluded" and j.distances == [None]
    j = judge(v, frame, CAM, model, xy, 0.0, None, horizon=h)  # margin None: off
    assert j.views[0].ok and j.distances[0] is not None


def test_covered_fraction_counts_each_column_once():
    rect = (100, 0, 200, 240)
    assert covered_fraction(rect, np.empty((0, 3))) == 0.0
    spans = np.array([[1.0, 80.0, 130.0], [1.0, 120.0, 150.0], [1.0, 190.0, 400.0]])
    assert covered_fraction(rect, spans) == pytest.approx(0.6)  # 100-150 and 190-200
    assert covered_fraction(rect, np.array([[1.0, 0.0, 50.0]])) == 0.0


@pytest.mark.parametrize("distance_limit", [2.5, 1.0])
def test_abstaining_keeps_matches_and_drops_rejections_behind_a_passer_by(distance_limit):
    """abstain_fraction: the target behind a passer-by the detector left out is judged on its
    whole rectangle; a match stands (threshold 2.5), a rejection (threshold 1.0) is reported
    unjudged instead."""
    v, frame, model = _histogram_on_grey()
    xy = np.array([[1.57, 0.12]])
    legs = [(-16.0, 1.2), (-15.0, 1.2), (-5.0, 1.2), (-4.0, 1.2), (4.0, 1.55), (5.0, 1.6)]
    h = _horizon(legs, far_m=6.0)
    kw = {"horizon": h, "horizon_margin_m": 0.3, "abstain_fraction": 0.25}
    j = judge(v, frame, CAM, model, xy, 0.0, distance_limit, **kw)
    whole = judge(v, frame, CAM, model, xy, 0.0, None)  # the same rectangle, judged
    assert whole.distances[0] is not None and 1.0 < whole.distances[0] <= 2.5
    if distance_limit == 2.5:
        assert j.views[0].ok and j.distances == whole.distances and j.chosen == 0
    else:
        assert j.views[0].status == "occluded" and j.distances == [None] and j.chosen == -1
