"""Every registered verifier: conformance, then what each should tell apart."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from followbot.services.vision_verify.core import Camera, ImageFeatures, Verifier, View, judge
from followbot.services.vision_verify.model import build_model
from followbot.services.vision_verify.verifiers import REGISTRY, make_verifier

from .helpers import HOW, acquired_scene, opencv_sample, owner

NAMES = ["face", "histogram", "meanshift"]


def test_the_three_verifiers_are_registered():
    assert set(NAMES) <= set(REGISTRY.names())
    with pytest.raises(ValueError, match="valid names"):
        make_verifier("nope")
    with pytest.raises(ValueError, match="verifier_settings"):
        make_verifier("histogram", {"colour_wieght": 2})


@pytest.mark.parametrize("name", NAMES)
def test_conformance(name):
    camera, acq, frames = acquired_scene()
    v = make_verifier(name)
    assert isinstance(v, Verifier) and v.name == name
    assert isinstance(v.default_threshold, float)
    model = build_model(v, camera, acq, 1)
    assert model.verifier == name and model.features
    for arr in model.features.values():
        assert arr.dtype == np.float32 and np.all(np.isfinite(arr))
    image, px, cands, _truth, _ = frames[-1]
    xy = np.array([[c.x_m, c.y_m] for c in cands.candidates] + [[-1.0, 0.0], [2.0, 5.0]])
    j = judge(v, ImageFeatures(px), camera, model, xy, image.pan_rad, None)
    assert len(j.distances) == len(xy)
    assert j.distances[-2] is None and j.distances[-1] is None  # behind, out of view
    for view, d in zip(j.views, j.distances, strict=True):
        assert (d is None) or (view.ok and d >= 0 and math.isfinite(d))
    # no candidate at all, or none in view: nothing chosen, no error
    assert judge(v, ImageFeatures(px), camera, model, np.zeros((0, 2)), 0.0, None).chosen == -1
    assert judge(v, ImageFeatures(px), camera, model, xy[-2:], 0.0, None).chosen == -1


@pytest.mark.parametrize("name", ["histogram", "meanshift"])
def test_appearance_verifiers_prefer_the_target_in_the_crossing(name):
    """t = 4..6 s: the bystander (yellow checks) crosses in front of the target (red)."""
    camera, acq, frames = acquired_scene()
    v = make_verifier(name)
    model = build_model(v, camera, acq, 1)
    right = judged = 0
    for image, px, cands, truth, _ in frames:
        if image.stamp_ns < 4.0e9:
            continue
        xy = np.array([[c.x_m, c.y_m] for c in cands.candidates]).reshape(-1, 2)
        j = judge(v, ImageFeatures(px), camera, model, xy, image.pan_rad, None)
        who = [owner(c, truth) for c in cands.candidates]
        seen = {who[i] for i, d in enumerate(j.distances) if d is not None}
        if {1, 2} <= seen:  # both people judged in this frame
            judged += 1
            right += who[j.chosen] == 1
    assert judged >= 5
    assert right / judged >= 0.8


def test_face_verifier_finds_a_real_face_and_checks_bearing_and_height():
    path = opencv_sample("messi5.jpg")
    if path is None:
        pytest.skip(f"opencv-doc's messi5.jpg {HOW}")
    img = cv2.imread(str(path))
    h, w = img.shape[:2]
    camera = Camera(width=w, height=h, hfov_deg=60.0, height_m=1.2)
    v = make_verifier("face")
    frame = ImageFeatures(img)
    faces = v.faces(frame)
    assert faces.shape[0] >= 1
    x, y, fw, fh = max(faces, key=lambda f: f[2])  # the player's face (the largest)
    u, vv = x + fw / 2, y + fh / 2
    bearing = float(camera.bearing(u))
    # put a candidate 4 m away on the face's bearing, and one 1.5 m to its right
    depth = 4.0
    on = [depth, depth * math.tan(bearing)]
    off = [depth, depth * math.tan(bearing) - 1.5]  # 20 deg right (the other face is left)
    view = View(
        index=0,
        x_m=on[0],
        y_m=on[1],
        depth_m=on[0],
        lateral_m=on[1],
        u_px=u,
        rect=(int(x), int(y), int(x + fw), int(y + fh)),
    )
    frame.cache["camera"] = camera
    learnt = v.learn(frame, view.rect, view)["face"]
    assert learnt[1] == 1.0  # a face was seen in the model rectangle
    rho = math.hypot(*on)
    assert learnt[0] == pytest.approx(1.2 - rho * math.tan(float(camera.elevation(vv))), abs=1e-3)
    from followbot.services.vision_verify.core import Model

    model = Model(
        model_id=1,
        verifier="face",
        x_m=on[0],
        y_m=on[1],
        depth_m=depth,
        rect_w_px=fw,
        rect_h_px=fh,
        image_width=w,
        image_height=h,
        features={"face": learnt},
    )
    j = judge(v, ImageFeatures(img), camera, model, np.array([on, off]), 0.0, v.default_threshold)
    assert j.distances[0] is not None and j.distances[0] < 0.2
    assert j.distances[1] == v.settings.no_face_distance
    assert j.chosen == 0
