"""core.checked_model: the one check a target model passes before it is used."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from followbot.schemas import Array, TargetModel, decode, encode
from followbot.services.vision_verify.core import (
    MAX_MODEL_ID,
    Camera,
    ImageFeatures,
    InvalidModel,
    adapt_features,
    checked_model,
)
from followbot.services.vision_verify.model import build_model
from followbot.services.vision_verify.verifiers import make_verifier

from .helpers import acquired_scene

CAMERAS = [Camera()]


def learnt(name: str = "histogram") -> TargetModel:
    """A model as the verifier learns it, through the wire encoding (as it arrives)."""
    camera, acq, _ = acquired_scene()
    model = build_model(make_verifier(name), camera, acq, 5)
    return decode(TargetModel, encode(model.to_message()))


def with_feature(msg: TargetModel, name: str, value: np.ndarray | None) -> TargetModel:
    features = dict(msg.features)
    if value is None:
        features.pop(name)
    else:
        features[name] = Array.from_numpy(value)
    return msgspec.structs.replace(msg, features=features)


def feature(msg: TargetModel, name: str) -> np.ndarray:
    return np.array(msg.features[name].numpy())


@pytest.mark.parametrize("name", ["face", "histogram", "meanshift"])
def test_every_verifiers_own_model_passes_and_keeps_its_features(name):
    msg = learnt(name)
    model = checked_model(msg, make_verifier(name), CAMERAS)
    assert model.model_id == 5 and set(model.features) == set(msg.features)
    for k, v in model.features.items():
        np.testing.assert_array_equal(v, msg.features[k].numpy())


def test_a_model_updated_online_still_passes():
    """Workers publish their adapted model; the others must accept it."""
    _, _, frames = acquired_scene()
    msg = learnt()
    v = make_verifier("histogram")
    model = checked_model(msg, v, CAMERAS)
    seen = v.describe(ImageFeatures(frames[-1][1]), (100, 40, 160, 200))
    for _ in range(20):
        model.features = adapt_features(model.features, seen, 0.3)
    checked_model(model.to_message(), v, CAMERAS)


def _colour(msg):
    return feature(msg, "colour_hs")


BAD = {
    # what a rogue or corrupt message may carry -> the check that refuses it
    "NaN colour bin": (
        lambda m: with_feature(m, "colour_hs", np.where(np.arange(216) == 3, np.nan, _colour(m))),
        "non_finite",
    ),
    "infinite edge bin": (
        lambda m: with_feature(m, "edge_orientation", np.full(72, np.inf, np.float32)),
        "non_finite",
    ),
    "float64 beyond float32": (
        lambda m: with_feature(m, "edge_orientation", np.full(72, 1e300)),
        "non_finite",
    ),
    "colour histogram of 100 bins": (
        lambda m: with_feature(m, "colour_hs", np.full(100, 0.01, np.float32)),
        "bad_features",
    ),
    "colour histogram summing to 2": (
        lambda m: with_feature(m, "colour_hs", 2 * _colour(m)),
        "bad_features",
    ),
    "negative bin (sum still 1)": (
        lambda m: with_feature(
            m, "colour_hs", np.r_[_colour(m)[:-2], _colour(m)[-2] + 0.5, -0.5].astype(np.float32)
        ),
        "bad_features",
    ),
    "colour histogram as uint8": (
        lambda m: with_feature(m, "colour_hs", np.zeros(216, np.uint8)),
        "bad_features",
    ),
    "all-zero colour histogram": (
        lambda m: with_feature(m, "colour_hs", np.zeros(216, np.float32)),
        "bad_features",
    ),
    "no edge histogram": (lambda m: with_feature(m, "edge_orientation", None), "bad_features"),
    "patch pixels without their rectangle": (
        lambda m: with_feature(m, "patch_rect", None),
        "bad_features",
    ),
    "patch rectangle outside the patch": (
        lambda m: with_feature(m, "patch_rect", np.array([0, 0, 5000, 10], np.float32)),
        "bad_features",
    ),
    "patch larger than the image": (
        lambda m: with_feature(m, "patch_bgr", np.zeros((300, 400, 3), np.uint8)),
        "bad_features",
    ),
    "unknown verifier": (lambda m: msgspec.structs.replace(m, verifier="nope"), "wrong_verifier"),
    "model_id 10^9": (lambda m: msgspec.structs.replace(m, model_id=10**9), "bad_model_id"),
    "model_id 0 (no model)": (lambda m: msgspec.structs.replace(m, model_id=0), "bad_model_id"),
    "image no camera has": (
        lambda m: msgspec.structs.replace(m, image_width=640, image_height=480),
        "unknown_image_size",
    ),
    "rectangle wider than the image": (
        lambda m: msgspec.structs.replace(m, rect_width_px=321.0),
        "bad_rectangle",
    ),
    "position behind the camera": (
        lambda m: msgspec.structs.replace(m, x_m=-2.0, y_m=0.0, pan_rad=0.0),
        "behind_camera",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_model_is_refused_naming_the_check(case):
    make_bad, kind = BAD[case]
    good = learnt()
    bad = decode(TargetModel, encode(make_bad(good)))  # it travels: the wire accepts it
    with pytest.raises(InvalidModel) as err:
        checked_model(bad, make_verifier("histogram"), CAMERAS)
    assert err.value.kind == kind, str(err.value)
    assert str(err.value)  # and says what is wrong


def test_the_largest_model_id_passes_and_one_more_does_not():
    v = make_verifier("histogram")
    checked_model(msgspec.structs.replace(learnt(), model_id=MAX_MODEL_ID), v, CAMERAS)
    with pytest.raises(InvalidModel, match=f"outside 1..{MAX_MODEL_ID}"):
        checked_model(msgspec.structs.replace(learnt(), model_id=MAX_MODEL_ID + 1), v, CAMERAS)


def test_features_over_the_size_bound_are_refused():
    msg = learnt()
    size = sum(len(a.data) for a in msg.features.values())
    v = make_verifier("histogram")
    checked_model(msg, v, CAMERAS, max_bytes=size)
    with pytest.raises(InvalidModel, match="bytes of features") as err:
        checked_model(msg, v, CAMERAS, max_bytes=size - 1)
    assert err.value.kind == "too_large"


def test_meanshift_checks_its_own_bins_and_mass():
    msg = learnt("meanshift")
    v = make_verifier("meanshift")  # 16 x 4 = 64 bins
    for name, value, match in [
        ("hs_upper", np.full(16, 1 / 16, np.float32), "64 bins"),
        ("hs_lower", np.full(64, 1 / 32, np.float32), "sums to 2"),
        ("mass", np.array([0.5, 1.5], np.float32), "densities in"),
    ]:
        with pytest.raises(InvalidModel, match=match):
            checked_model(with_feature(msg, name, value), v, CAMERAS)
    # a model learnt with other bins does not fit this worker's settings
    other = make_verifier("meanshift", {"sat_bins": 1})
    with pytest.raises(InvalidModel, match="16 bins"):
        checked_model(msg, other, CAMERAS)


def test_face_checks_its_height_and_flag():
    msg = learnt("face")
    v = make_verifier("face")
    with pytest.raises(InvalidModel, match="found flag"):
        checked_model(with_feature(msg, "face", np.array([1.6, 0.5], np.float32)), v, CAMERAS)
    with pytest.raises(InvalidModel, match="2 floats"):
        checked_model(with_feature(msg, "face", np.array([1.6], np.float32)), v, CAMERAS)
