import math

import numpy as np
import pytest

from followbot.services.sim.simulation import Simulation

from .helpers import scenario, standing

GREEN = [0, 255, 0]
RED = [255, 0, 0]
BLUE = [0, 0, 255]


def _person(pid, x, y, shirt, **kw):
    return standing(pid, x, y, appearance={"shirt_rgb": shirt, "pattern": "plain"}, **kw)


def _shirt_columns(img, row, rgb):
    """Columns of the longest run of shirt-coloured pixels on one row."""
    bgr = np.array(rgb[::-1])
    cols = np.flatnonzero(np.all(np.abs(img[row].astype(int) - bgr) <= 2, axis=1))
    if cols.size == 0:
        return cols
    runs = np.split(cols, np.flatnonzero(np.diff(cols) > 1) + 1)
    return max(runs, key=len)


@pytest.mark.parametrize("pan_deg", [0.0, 10.0, 25.0, 30.0])
def test_torso_is_at_the_expected_column_for_the_pan_angle(pan_deg):
    px, py = 3.0, 1.0
    # facing the robot so the torso is symmetric about its centre
    sim = Simulation(scenario(people=[_person(1, px, py, GREEN, heading_deg=180 + 18.4)]))
    sim.command_pan(math.radians(pan_deg))
    sim.advance_to(500_000_000)  # the pan unit needs < 0.3 s at 90 deg/s
    assert sim.robot.pan_rad == pytest.approx(math.radians(pan_deg))
    msg = sim.image()
    assert msg.pan_rad == pytest.approx(math.radians(pan_deg))
    img = msg.pixels()
    cam = sim.camera
    pan = math.radians(pan_deg)
    x_c = math.cos(pan) * px + math.sin(pan) * py
    y_c = -math.sin(pan) * px + math.cos(pan) * py
    u_expected = cam.width / 2 - cam.focal_px * y_c / x_c  # DESIGN.md: u = W/2 - f y / x
    row = round(cam.row(x_c, 1.2))
    cols = _shirt_columns(img, row, GREEN)
    assert cols.size > 10
    assert (cols.min() + cols.max() + 1) / 2 == pytest.approx(u_expected, abs=1.5)


def test_focal_length_matches_the_thesis_camera():
    sim = Simulation(scenario())
    assert sim.camera.focal_px == pytest.approx(160 / math.tan(math.radians(23.75)))
    assert sim.camera.focal_px == pytest.approx(363, abs=1)


@pytest.mark.parametrize(("near", "far"), [(RED, BLUE), (BLUE, RED)])
def test_nearer_person_hides_the_farther(near, far):
    sc = scenario(people=[_person(1, 4.0, 0.0, far), _person(2, 2.0, 0.0, near)])
    img = Simulation(sc).image_pixels()
    centre = img[120, 160].astype(int)
    assert np.abs(centre - np.array(near[::-1])).max() <= 2


def test_person_outside_the_field_of_view_is_not_drawn_and_not_visible():
    sim = Simulation(scenario(people=[_person(1, 1.0, 3.0, GREEN)]))
    assert _shirt_columns(sim.image_pixels(), 120, GREEN).size == 0
    assert not sim.truth().people[0].visible_camera


def test_lighting_gain_darkens_the_image():
    bright = Simulation(scenario(people=[_person(1, 2.0, 0.0, GREEN)])).image_pixels()
    dark = Simulation(
        scenario(people=[_person(1, 2.0, 0.0, GREEN)], lighting=[{"t_s": 0.0, "gain": 0.5}])
    ).image_pixels()
    ratio = dark.astype(float).mean() / bright.astype(float).mean()
    assert ratio == pytest.approx(0.5, abs=0.03)


def test_noise_and_texture_give_edges():
    sc = scenario(
        world={"walls": [{"points": [[5, -5], [5, 5]]}]},
        people=[standing(1, 2.5, 0.0, appearance={"pattern": "stripes"})],
        camera={"noise_std": 3.0},
    )
    img = Simulation(sc).image_pixels()
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    grey = img.astype(float).mean(axis=2)
    # stripes: strong vertical intensity changes down the torso's centre column
    assert np.abs(np.diff(grey[60:120, 160])).max() > 20
    # noise: a flat ceiling patch is not flat
    assert grey[2:10, 2:40].std() > 1.0
