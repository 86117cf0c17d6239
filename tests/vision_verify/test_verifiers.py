"""Every registered verifier: conformance, then what each should tell apart."""

from __future__ import annotations

import math

import cv2
import msgspec
import numpy as np
import pytest

from followbot.services.vision_verify.core import (
    Camera,
    ImageFeatures,
    Verifier,
    View,
    judge,
    project,
)
from followbot.services.vision_verify.model import build_model
from followbot.services.vision_verify.verifiers import REGISTRY, make_verifier

from .helpers import HOW, acquired_scene, opencv_sample, owner

NAMES = ["colour", "face", "histogram", "meanshift", "online"]


def test_the_three_verifiers_are_registered():
    assert set(NAMES) <= set(REGISTRY.names())
    with pytest.raises(ValueError, match="valid names"):
        make_verifier("nope")
    with pytest.raises(ValueError, match=r"verifier 'histogram': .*colour_wieght"):
        make_verifier("histogram", {"colour_wieght": 2})


@pytest.mark.parametrize("name", NAMES)
def test_conformance(name):
    camera, acq, frames = acquired_scene()
    v = make_verifier(name)
    assert isinstance(v, Verifier) and v.name == name
    assert isinstance(v.default_threshold, float)
    model = build_model(v, camera, acq, 1)
    assert model.verifier == name and model.features
    for arr in model.features.values():  # histograms, or the pixels they were learnt from
        assert arr.dtype in (np.float32, np.uint8) and np.all(np.isfinite(arr))
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


@pytest.mark.parametrize("name", ["histogram", "meanshift", "online"])
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


@pytest.mark.parametrize("closer", [1.5, 2.0])
def test_a_target_closer_than_when_learnt_is_compared_with_the_same_part_of_the_model(closer):
    """The target at 1/closer of its learning distance: the image clips its head and feet.
    Compared with the same rows of the model's pixels, it is nearer to the model than when
    compared with the whole model (the thesis's way, ``match_windows`` off)."""
    camera, acq, _frames = acquired_scene()
    v = make_verifier("histogram")
    whole = make_verifier("histogram", {"match_windows": False})
    model = build_model(v, camera, acq, 1)
    x0, y0, x1, y1 = acq.rect
    person = acq.bgr[y0:y1, x0:x1]
    xy = np.array([[acq.x_m / closer, acq.y_m / closer]])
    (view,) = project(camera, xy, acq.pan_rad, model.rect_w_px, model.rect_h_px, model.depth_m)
    bx0, by0, bx1, by1 = (round(c) for c in view.body)
    assert by0 < 0 and by1 > acq.bgr.shape[0]  # clipped top and bottom
    big = cv2.resize(person, (bx1 - bx0, by1 - by0), interpolation=cv2.INTER_LINEAR)
    frame = np.full_like(acq.bgr, 128)
    h, w = frame.shape[:2]
    sx, sy = max(0, -bx0), max(0, -by0)
    dx, dy = max(0, bx0), max(0, by0)
    cw, ch = min(w - dx, big.shape[1] - sx), min(h - dy, big.shape[0] - sy)
    frame[dy : dy + ch, dx : dx + cw] = big[sy : sy + ch, sx : sx + cw]
    d_windows = judge(v, ImageFeatures(frame), camera, model, xy, acq.pan_rad, None).distances
    d_whole = judge(whole, ImageFeatures(frame), camera, model, xy, acq.pan_rad, None).distances
    assert d_windows[0] < d_whole[0] - 0.1


def test_a_model_without_its_pixels_is_compared_whole():
    """A model saved before the pixels were kept (or by another implementation) still works:
    every candidate is compared with the whole model."""
    camera, acq, frames = acquired_scene()
    v = make_verifier("histogram")
    model = build_model(v, camera, acq, 1)
    old = msgspec.structs.replace(
        model, features={k: model.features[k] for k in ("colour_hs", "edge_orientation")}
    )
    whole = make_verifier("histogram", {"match_windows": False})
    image, px, cands, _truth, _ = frames[-1]
    xy = np.array([[c.x_m, c.y_m] for c in cands.candidates]).reshape(-1, 2)
    got = judge(v, ImageFeatures(px), camera, old, xy, image.pan_rad, None).distances
    want = judge(whole, ImageFeatures(px), camera, model, xy, image.pan_rad, None).distances
    assert got == want
