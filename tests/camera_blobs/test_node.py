"""camera_blobs as a stage: the simulator's frames -> candidates on the floor where the people
stand (laser frame, with their image regions), and settings that name no colour refused."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from followbot.schemas import Image, PersonCandidates
from followbot.services.camera_blobs.core import ColourModel
from followbot.services.camera_blobs.node import (
    BlobFinder,
    CameraBlobsSettings,
    _Frame,
    check,
)
from followbot.services.runtime.ground_plane import GroundCamera
from followbot.services.runtime.mount import LaserMount


def _first_frame(name: str):
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation

    sim = Simulation(load_builtin(name))
    while True:
        for msg in sim.tick():
            if isinstance(msg, Image):
                return sim, msg, sim.truth()


def _camera(sim) -> GroundCamera:
    cs = sim.scenario.camera
    return GroundCamera(
        width=cs.width, height=cs.height, hfov_deg=cs.hfov_deg, height_m=cs.height_m,
        mount_x_m=cs.mount_x_m,
    )  # fmt: skip


def _trousers_rect(cam: GroundCamera, x_m: float, y_m: float) -> list[float]:
    """A rectangle on the trousers (0.1-0.4 m above the floor) of a person standing at (x, y)."""
    u, v = cam.floor_to_pixel(x_m, y_m)
    d = math.hypot(x_m - cam.mount_x_m, y_m)
    half = cam.focal_px * 0.05 / d
    return [float(u) - half, float(v) - cam.focal_px * 0.4 / d, 2 * half, cam.focal_px * 0.3 / d]


@pytest.mark.parametrize("mount", [LaserMount(), LaserMount(x_m=0.3, y_m=-0.1, yaw_deg=20)])
def test_people_in_the_target_colour_are_candidates_where_they_stand(mount):
    sim, img, truth = _first_frame("zhuang_same_colour")
    cam = _camera(sim)
    target = next(p for p in truth.people if p.is_target)
    rect = _trousers_rect(cam, target.robot_x_m, target.robot_y_m)
    s = CameraBlobsSettings(learn_rect=rect, camera=cam, laser_mount=mount)
    check(s)
    finder = BlobFinder(s)
    boxes = finder.regions_of(img.pixels())
    frame = _Frame(img.stamp_ns, img.pan_rad, img.width, img.height, boxes)
    cands = finder.candidates(frame, mount)
    msg = PersonCandidates(stamp_ns=1, frame_id="laser", candidates=cands, image_width=img.width)
    msgspec.msgpack.decode(msgspec.msgpack.encode(msg), type=PersonCandidates)  # valid on wire
    base = mount.to_base([[c.x_m, c.y_m] for c in cands])
    seen = [p for p in truth.people if p.visible_camera]
    assert target in seen
    for person in seen:  # everyone in view in the target's red is found
        d = np.hypot(base[:, 0] - person.robot_x_m, base[:, 1] - person.robot_y_m)
        assert d.min() < 0.35, (person.id, base, person)
        c = cands[int(np.argmin(d))]
        assert c.box_px is not None and c.pattern == "blob"
        assert c.range_m == pytest.approx(math.hypot(c.x_m, c.y_m))
        assert 0.1 < c.width_m < 0.6  # a pair of trousers, not a wall


def test_a_grey_learning_rectangle_gives_no_candidates_and_says_why():
    sim, img, _ = _first_frame("zhuang_corridor")
    s = CameraBlobsSettings(learn_rect=[150.0, 5.0, 20.0, 20.0], camera=_camera(sim))  # the wall
    finder = BlobFinder(s)
    assert len(finder.regions_of(img.pixels())) == 0
    assert "too grey" in finder.colour_error and finder.colour is None


def test_given_thresholds_need_no_learning():
    sim, img, _ = _first_frame("zhuang_corridor")
    red = ColourModel(hue_lo=170.0, hue_hi=10.0, sat_lo=100.0, sat_hi=255.0)
    finder = BlobFinder(CameraBlobsSettings(colour=red, camera=_camera(sim)))
    assert len(finder.regions_of(img.pixels())) >= 1


@pytest.mark.parametrize(
    ("values", "says"),
    [
        ({}, "needs the target's colour"),
        (
            {"learn_rect": [1, 1, 5, 5], "colour": {"hue_lo": 1, "hue_hi": 2, "sat_lo": 50,
                                                     "sat_hi": 90}},
            "exactly one",
        ),
        ({"learn_rect": [300, 100, 40, 40]}, "not inside the camera's 320x240 image"),
        ({"learn_rect": [10, 10, 0, 40]}, "width and height must be > 0"),
    ],
)  # fmt: skip
def test_settings_without_a_usable_colour_are_refused_with_the_reason(values, says):
    s = msgspec.convert(values, CameraBlobsSettings)
    with pytest.raises(ValueError, match=says):
        check(s)
