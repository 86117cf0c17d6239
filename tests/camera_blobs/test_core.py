"""Seed 001 3.1-3.2: colour learnt in H and S from the target's rectangle, pixels classified,
connected regions reported as rectangles; on synthetic frames and the simulator's camera."""

from __future__ import annotations

import numpy as np
import pytest

from followbot.services.camera_blobs.core import (
    BlobSettings,
    ColourError,
    classify,
    learn_colour,
    regions,
)
from followbot.services.runtime.ground_plane import GroundCamera


def frame(*rects, size=(240, 320)):
    """A grey frame with filled BGR rectangles ((x0, y0, x1, y1), bgr)."""
    import cv2

    img = np.full((*size, 3), 120, np.uint8)
    for (x0, y0, x1, y1), bgr in rects:
        cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), bgr, -1)
    return img


def test_a_learnt_colour_finds_its_region_and_only_it():
    img = frame(((100, 60, 140, 200), (30, 40, 200)), ((200, 80, 240, 200), (200, 60, 30)))
    model = learn_colour(img, (105, 70, 30, 40))
    (r,) = regions(classify(img, model))
    assert r == pytest.approx([120, 130, 40, 140])


def test_reds_whose_hue_wraps_past_zero_are_learnt_as_one_range():
    # BGR pure-ish reds on both sides of hue 0: (0, 10, 200) is hue ~177, (10, 0, 200) ~3
    img = frame(((50, 50, 70, 150), (10, 0, 200)), ((70, 50, 90, 150), (0, 10, 200)))
    model = learn_colour(img, (50, 50, 40, 100))
    assert model.hue_lo > model.hue_hi  # wraps
    (r,) = regions(classify(img, model))
    assert r == pytest.approx([70, 100, 40, 100])


def test_brightness_does_not_matter_only_hue_and_saturation():
    img = frame(((40, 40, 80, 120), (40, 80, 220)), ((200, 40, 240, 120), (20, 40, 110)))
    model = learn_colour(img, (45, 45, 30, 70))
    boxes = regions(classify(img, model))
    assert len(boxes) == 2  # the same clothing in shade is still the target's colour


def test_a_grey_rectangle_is_refused_with_the_reason():
    img = frame(((40, 40, 80, 120), (90, 90, 90)))
    with pytest.raises(ColourError, match="too grey"):
        learn_colour(img, (45, 45, 30, 70))
    with pytest.raises(ColourError, match="no pixel"):
        learn_colour(img, (400, 400, 10, 10))


def test_specks_smaller_than_min_area_are_not_regions():
    img = frame(((40, 40, 80, 120), (40, 80, 220)), ((200, 40, 204, 44), (40, 80, 220)))
    model = learn_colour(img, (45, 45, 30, 70))
    assert len(regions(classify(img, model), BlobSettings(min_area_px=40))) == 1
    assert len(regions(classify(img, model), BlobSettings(min_area_px=4))) == 2


def _sim_frame(people, robot_pose=(0.0, 0.0, 0.0), noise=3.0, seed=0):
    from followbot.services.sim.camera import CameraModel
    from followbot.services.sim.people import Person
    from followbot.services.sim.scenario import CameraSpec, PersonSpec, WorldSpec
    from followbot.services.sim.world import StaticWorld

    rng = np.random.default_rng(seed)
    cam = CameraModel(CameraSpec(noise_std=noise), StaticWorld.from_spec(WorldSpec()), rng)
    drawn = []
    for p in people:
        spec = PersonSpec(**p)
        drawn.append((Person(spec).state(0.0), spec.appearance, 0.06))
    return cam.render(robot_pose, 0.0, drawn, 1.0, rng), cam


def test_in_the_simulator_the_trousers_region_stands_where_the_person_stands():
    from followbot.services.sim.scenario import AppearanceSpec

    look = AppearanceSpec(trousers_rgb=(200, 40, 40), shirt_rgb=(230, 230, 230))
    # a level camera 1 m high sees the floor from 3 m on: the person stands at 4 m
    img, _ = _sim_frame([{"id": 1, "start": (4.0, 0.4), "heading_deg": 180, "appearance": look}])
    u, v = GroundCamera().floor_to_pixel(4.0, 0.4)
    model = learn_colour(img, (int(u) - 4, int(v) - 30, 8, 20))
    r = regions(classify(img, model))[0]
    assert abs(r[0] - float(u)) < 4
    # the bottom edge of the trousers is on the floor (they reach past the shoes' sides)
    cam = GroundCamera()
    fx, fy = cam.pixel_to_floor(r[0], r[1] + r[3] / 2)
    assert np.hypot(float(fx) - 4.0, float(fy) - 0.4) < 0.15


def test_a_bystander_in_the_same_colour_is_a_second_region():
    from followbot.services.sim.scenario import AppearanceSpec

    look = AppearanceSpec(trousers_rgb=(200, 40, 40))
    img, _ = _sim_frame(
        [
            {"id": 1, "start": (2.5, 0.5), "heading_deg": 180, "appearance": look},
            {"id": 2, "start": (3.0, -0.6), "heading_deg": 180, "appearance": look},
        ]
    )
    cam = GroundCamera()
    u, v = cam.floor_to_pixel(2.5, 0.5)
    model = learn_colour(img, (int(u) - 6, int(v) - 40, 12, 30))
    assert len(regions(classify(img, model))) == 2
