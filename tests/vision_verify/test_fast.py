"""The fast histograms of core.ImageFeatures against the plain computation (reference.py).

The fast path (a per-frame colour-bin index image, gradients per rectangle grown by a pixel,
work arrays reused between calls) must give exactly the histograms and distances of the
whole-frame computation it replaced, on any image and any rectangle.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from followbot.services.vision_verify.core import (
    HALF_BINS,
    ImageFeatures,
    colour_histogram,
    edge_histogram,
    judge,
)
from followbot.services.vision_verify.model import build_model
from followbot.services.vision_verify.reference import (
    ReferenceFeatures,
    ReferenceHistogramVerifier,
)
from followbot.services.vision_verify.verifiers import make_verifier

from .helpers import acquired_scene


def _image(kind: int, h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    if kind == 1:  # smooth texture: gradients of every direction and strength
        img = cv2.GaussianBlur(img, (7, 7), 2)
    elif kind == 2:  # few levels: flat regions, step edges at 0/90/180/270 deg, grey and dark
        img = (img // 64 * 85).astype(np.uint8)
    elif kind == 3:  # blocks of plain colour
        small = rng.integers(0, 256, (max(1, h // 8), max(1, w // 8), 3), dtype=np.uint8)
        img = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    return img


@settings(max_examples=80, deadline=None)
@given(
    st.integers(0, 3),
    st.integers(1, 90),
    st.integers(1, 120),
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(*[st.floats(0, 1)] * 4), min_size=1, max_size=6),
)
def test_histograms_equal_the_reference_on_random_images(kind, h, w, seed, corners):
    img = _image(kind, h, w, seed)
    fast, ref = ImageFeatures(img), ReferenceFeatures(img)
    for a, b, c, d in corners:  # any rectangle, at the border or inside, 1 px and up
        x0, y0 = int(a * (w - 1)), int(b * (h - 1))
        x1, y1 = x0 + 1 + int(c * (w - x0 - 1)), y0 + 1 + int(d * (h - y0 - 1))
        rect = (x0, y0, x1, y1)
        np.testing.assert_array_equal(fast.colour(rect), ref.colour(rect), err_msg=str(rect))
        np.testing.assert_array_equal(fast.edges(rect), ref.edges(rect), err_msg=str(rect))
    whole = (0, 0, w, h)
    np.testing.assert_array_equal(colour_histogram(img), ref.colour(whole))
    np.testing.assert_array_equal(edge_histogram(img), ref.edges(whole))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 3), st.integers(0, 2**32 - 1), st.integers(2, 10))
def test_shared_gradients_give_the_same_edges(kind, seed, n):
    """Overlapping rectangles share one gradient computation (share_gradients); rectangles
    outside its box fall back to their own. Same histograms as the reference either way."""
    img = _image(kind, 120, 160, seed)
    rng = np.random.default_rng(seed)
    x0 = rng.integers(0, 100, n)
    rects = [(int(a), 10, int(a) + 60, 110) for a in x0]  # 60 x 100, all at the same rows
    fast, ref = ImageFeatures(img), ReferenceFeatures(img)
    fast.share_gradients(rects)
    box_area = (max(r[2] for r in rects) - min(r[0] for r in rects)) * 100
    assert (fast._block is not None) == (n * 6000 > 1.5 * box_area)
    for rect in [*rects, (0, 0, 160, 120), (5, 0, 30, 9)]:
        np.testing.assert_array_equal(fast.edges(rect), ref.edges(rect), err_msg=str(rect))


def test_colour_index_follows_the_rule_for_every_hue_and_saturation():
    """Every (H, S) at brightness levels around the V >= 51 threshold, and every (S, V) at
    a few hues: the bin is 10 hue_bin + sat_bin, or 100 + v_bin for pale or dark pixels."""
    h, s = np.meshgrid(np.arange(180), np.arange(256), indexing="ij")
    for v in (0, 31, 32, 50, 51, 52, 128, 255):
        hsv = np.dstack([h, s, np.full_like(h, v)]).astype(np.uint8)
        _check_index(hsv)
    s, v = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    for hue in (0, 17, 18, 19, 90, 161, 162, 179):
        hsv = np.dstack([np.full_like(s, hue), s, v]).astype(np.uint8)
        _check_index(hsv)


def _check_index(hsv: np.ndarray) -> None:
    frame = ImageFeatures(np.zeros_like(hsv))
    frame._hsv = hsv  # the index is computed from the frame's HSV when there is one
    h, s, v = (hsv[..., k].astype(np.int64) for k in range(3))
    colour = (s >= 51) & (v >= 51)
    want = np.where(colour, (h * 10 // 180) * 10 + s * 10 // 256, 100 + v * 8 // 256)
    got = frame.colour_index()
    np.testing.assert_array_equal(got, want)
    assert got.max() < HALF_BINS


def test_work_arrays_are_not_shared_between_results():
    """Histograms of one frame stay put while other frames, of other sizes, are judged."""
    a, b = _image(1, 120, 160, 1), _image(0, 240, 320, 2)
    fa, fb = ImageFeatures(a), ImageFeatures(b)
    rect = (10, 5, 90, 110)
    ca, ea = fa.colour(rect), fa.edges(rect)
    keep = ca.copy(), ea.copy()
    fb.colour((0, 0, 320, 240)), fb.edges((0, 0, 320, 240)), fb.edges((3, 4, 20, 30))
    np.testing.assert_array_equal(ca, keep[0])
    np.testing.assert_array_equal(ea, keep[1])
    np.testing.assert_array_equal(fa.colour(rect), keep[0])
    np.testing.assert_array_equal(fa.edges(rect), keep[1])
    assert not np.array_equal(fb.colour(rect), keep[0])


@pytest.mark.parametrize("threshold", [None, 0.8])
def test_judgements_on_simulator_frames_equal_the_reference(threshold):
    camera, acq, frames = acquired_scene()
    fast_v = make_verifier("histogram")
    model = build_model(fast_v, camera, acq, 1)
    ref_v = ReferenceHistogramVerifier()
    compared = 0
    for image, px, cands, _truth, _ in frames:
        xy = np.array([[c.x_m, c.y_m] for c in cands.candidates]).reshape(-1, 2)
        j = judge(fast_v, ImageFeatures(px), camera, model, xy, image.pan_rad, threshold)
        r = judge(ref_v, ReferenceFeatures(px), camera, model, xy, image.pan_rad, threshold)
        assert j.distances == r.distances
        assert j.chosen == r.chosen
        compared += sum(d is not None for d in j.distances)
    assert compared >= 20
