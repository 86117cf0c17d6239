"""The colour verifier (seed 001): a box is judged by how much of it one region of the learnt
colour fills; a model rectangle with no colour to learn judges nothing."""

from __future__ import annotations

import numpy as np
import pytest

from followbot.services.vision_verify.core import ImageFeatures, Model, View
from followbot.services.vision_verify.verifiers import make_verifier


def _people() -> np.ndarray:
    """A grey frame with three 'people' 40x100: a red shirt, a red shirt in shade, a blue one."""
    img = np.full((240, 320, 3), 110, np.uint8)
    for x0, bgr in ((20, (40, 40, 200)), (120, (20, 20, 100)), (220, (200, 60, 30))):
        img[60:160, x0 : x0 + 40] = (60, 60, 60)  # dark trousers and head
        img[75:115, x0 : x0 + 40] = bgr  # the shirt, rows 0.15-0.55 of the box
    return img


def _view(i: int, x0: int) -> View:
    return View(index=i, x_m=3.0, y_m=0.0, rect=(x0, 60, x0 + 40, 160))


def _model(v, frame: ImageFeatures, rect) -> Model:
    feats = v.learn(frame, rect, _view(0, rect[0]))
    model = Model(
        model_id=1, verifier="colour", x_m=3.0, y_m=0.0, depth_m=3.0, rect_w_px=40.0,
        rect_h_px=100.0, image_width=320, image_height=240, features=feats,
    )  # fmt: skip
    v.check_model(model)
    return model


def test_the_box_in_the_learnt_colour_wins_shade_or_not_and_passes_the_threshold():
    v = make_verifier("colour")
    frame = ImageFeatures(_people())
    model = _model(v, frame, (20, 60, 60, 160))
    red, shaded, blue = v.distances(frame, [_view(0, 20), _view(1, 120), _view(2, 220)], model)
    assert red == pytest.approx(0.6, abs=0.01)  # the shirt fills 40 % of the box
    assert shaded == pytest.approx(red)  # intensity is ignored (seed 3.1)
    assert blue == 1.0
    assert red <= v.default_threshold < blue


def test_a_grey_person_gives_a_model_that_judges_no_box():
    v = make_verifier("colour")
    img = _people()
    img[75:115, 20:60] = (150, 150, 150)  # a grey shirt: nothing to learn
    frame = ImageFeatures(img)
    model = _model(v, frame, (20, 60, 60, 160))
    assert v.distances(frame, [_view(0, 20), _view(1, 120)], model) == [None, None]


def test_a_learn_window_outside_the_rectangle_is_refused():
    with pytest.raises(ValueError, match="learn_window"):
        make_verifier("colour", {"learn_window": [0.5, 0.2, 0.4, 0.5]})
