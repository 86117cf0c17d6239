"""The camera's realism (issue 36): motion blur, softness, compression, shade, random dress."""

import math

import numpy as np
import pytest

from followbot.research.camera_realism import edge_widths
from followbot.services.sim.dress import dressed, pedestrian
from followbot.services.sim.scenario import ScenarioError, load_builtin, parse_scenario
from followbot.services.sim.simulation import Simulation

from .helpers import scenario, standing

GREEN = [40, 160, 60]


def _walker(speed_mps: float) -> dict:
    """A person crossing the view from left to right, 3 m ahead (at the centre at t = 2 s)."""
    return {
        "id": 1,
        "start": [3.0, 2.0 * speed_mps],
        "heading_deg": -90.0,
        "speed_mps": speed_mps,
        "path": [{"kind": "walk", "to": [3.0, -10.0]}],
        "appearance": {"shirt_rgb": GREEN, "pattern": "plain"},
    }


def _torso_edge_width(speed_mps: float, exposure_ms: float = 30.0) -> float:
    """Mean width (px) of the vertical edges on the rows of the walker's torso at t = 2 s."""
    sim = Simulation(scenario(people=[_walker(speed_mps)], camera={"exposure_ms": exposure_ms}))
    sim.advance_to(2_000_000_000)
    img = sim.image_pixels()
    grey = img.astype(np.float32).mean(axis=2)
    return float(np.mean(edge_widths(grey[95:125], min_peak=5.0)))


def test_blur_grows_with_the_persons_speed():
    widths = [_torso_edge_width(v) for v in (0.05, 0.8, 1.6)]
    assert widths[0] < 1.6  # standing still: a hard polygon edge
    assert widths[0] < widths[1] < widths[2]
    # 1.6 m/s at 3 m with 30 ms: a smear of f 0.048 / 3 ~ 5.8 px
    assert widths[2] > 3.5


def test_no_exposure_no_blur_even_when_walking_fast():
    assert _torso_edge_width(1.6, exposure_ms=0.0) < 1.6


def test_the_robots_turn_smears_the_whole_frame():
    sc = scenario(
        world={"walls": [{"points": [[4, -6], [4, 6]]}]},
        camera={"exposure_ms": 30.0},
    )
    sharp = Simulation(sc)
    turning = Simulation(sc)
    turning.command_velocity(0.0, 1.5)
    turning.advance_to(400_000_000)  # at full rate (1.5 rad/s), before the command expires
    assert turning.robot.w_radps == pytest.approx(1.5)
    sharp.advance_to(400_000_000)
    w_sharp = np.mean(edge_widths(sharp.image_pixels().mean(axis=2), min_peak=3.0))
    w_turn = np.mean(edge_widths(turning.image_pixels().mean(axis=2), min_peak=1.0))
    assert w_sharp < 1.5
    assert w_turn > 8.0  # f 1.5 rad/s 30 ms ~ 16 px of smear


def test_renders_are_deterministic_with_every_effect_on():
    sc = load_builtin("lookalikes")
    frames = []
    for _ in range(2):
        sim = Simulation(sc)
        sim.command_velocity(0.5, 0.8)
        sim.advance_to(3_000_000_000)
        frames.append(sim.image_pixels())
    assert np.array_equal(frames[0], frames[1])


def test_defaults_leave_the_effects_off():
    spec = scenario().camera
    assert spec.exposure_ms == 0.0 and spec.optics_blur_px == 0.0 and spec.jpeg_quality is None
    assert scenario().world.light_zones == []


def test_a_person_in_shade_is_darker_than_one_in_light():
    zones = [{"centre": [3.0, 1.0], "size_m": [1.0, 1.0], "gain": 0.5, "edge_m": 0.2}]
    people = [
        standing(1, 3.0, 1.0, appearance={"shirt_rgb": GREEN, "pattern": "plain"}),
        standing(2, 3.0, -1.0, appearance={"shirt_rgb": GREEN, "pattern": "plain"}),
    ]
    sim = Simulation(scenario(world={"light_zones": zones}, people=people))
    img = sim.image_pixels().astype(float)
    cam = sim.camera
    row = round(cam.row(3.0, 1.2))
    shade = img[row, round(cam.column(3.0, 1.0))]
    lit = img[row, round(cam.column(3.0, -1.0))]
    assert lit == pytest.approx(np.array(GREEN[::-1], dtype=float), abs=2)
    assert shade == pytest.approx(0.5 * lit, abs=2)


def test_jpeg_and_softness_change_the_frame_but_not_its_layout():
    people = [standing(1, 3.0, 0.0, appearance={"shirt_rgb": GREEN, "pattern": "plain"})]
    plain = Simulation(scenario(people=people)).image_pixels().astype(float)
    soft = Simulation(
        scenario(people=people, camera={"optics_blur_px": 1.0, "jpeg_quality": 60})
    ).image_pixels()
    soft = soft.astype(float)
    assert not np.array_equal(plain, soft)
    assert np.abs(plain - soft).mean() < 6.0
    assert np.mean(edge_widths(soft.mean(axis=2))) > np.mean(edge_widths(plain.mean(axis=2)))


def test_pedestrian_outfits_are_mostly_dark_grey_and_blue():
    rng = np.random.default_rng(1)
    looks = [pedestrian(rng) for _ in range(400)]

    def saturation(rgb):
        return (max(rgb) - min(rgb)) / max(1, max(rgb))

    tops = np.array([saturation(a.shirt_rgb) for a in looks])
    dark_trousers = np.mean([max(a.trousers_rgb) < 80 for a in looks])
    blue_trousers = np.mean([a.trousers_rgb[2] > a.trousers_rgb[0] + 20 for a in looks])
    assert np.median(tops) < 0.4  # no saturated primaries for most people
    assert np.mean(tops > 0.8) < 0.05
    assert dark_trousers + blue_trousers > 0.7


def _dressed(spread: float):
    people = [
        {"id": 1, "start": [3, 0], "appearance": {"shirt_rgb": [120, 60, 60]}},
        {"id": 2, "start": [4, 0], "dress": {"style": "lookalike", "of": 1,
                                             "colour_spread": spread}},
    ]  # fmt: skip
    sc = scenario(people=people)
    return dressed(sc.people, 5)


@pytest.mark.parametrize("spread", [10.0, 30.0, 60.0])
def test_lookalike_colours_are_near_the_targets_but_not_the_same(spread):
    looks = _dressed(spread)
    target, look = looks[1], looks[2]
    for a, b in ((target.shirt_rgb, look.shirt_rgb), (target.trousers_rgb, look.trousers_rgb)):
        d = math.dist(a, b)
        assert 0.5 * spread - 1.0 <= d <= spread + 1.0  # rounding to whole grey levels
    assert look.pattern == target.pattern


def test_dress_is_drawn_per_person_and_seed():
    people = [{"id": i, "start": [i, 0], "dress": {"style": "pedestrian"}} for i in (1, 2)]
    a = dressed(scenario(people=people).people, 3)
    b = dressed(scenario(people=people[1:]).people, 3)
    assert a[2] == b[2]  # person 2's outfit does not depend on person 1 being there
    assert a[1] != a[2]
    assert dressed(scenario(people=people).people, 4)[2] != a[2]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"camera": {"exposure_ms": -1.0}}, "exposure_ms"),
        ({"camera": {"jpeg_quality": 0}}, "jpeg_quality"),
        ({"camera": {"optics_blur_px": 9.0}}, "optics_blur_px"),
        ({"world": {"light_zones": [{"centre": [0, 0], "size_m": [1, 1], "gain": -1}]}}, "gain"),
        ({"people": [{"id": 1, "start": [1, 0], "dress": {"style": "lookalike"}}]}, "needs `of`"),
        (
            {"people": [{"id": 1, "start": [1, 0], "dress": {"style": "lookalike", "of": 1}}]},
            "cannot copy itself",
        ),
        (
            {"people": [{"id": 1, "start": [1, 0], "dress": {"style": "lookalike", "of": 7}}]},
            "no person 7",
        ),
        (
            {
                "people": [
                    {"id": 1, "start": [1, 0]},
                    {"id": 2, "start": [2, 0], "dress": {"style": "lookalike", "of": 1}},
                    {"id": 3, "start": [3, 0], "dress": {"style": "lookalike", "of": 2}},
                ]
            },
            "itself a lookalike",
        ),
        ({"people": [{"id": 1, "start": [1, 0], "dress": {"style": "twin"}}]}, "style"),
    ],
)
def test_bad_settings_are_refused_naming_the_fault(change, message):
    with pytest.raises(ScenarioError, match=message):
        parse_scenario({"name": "bad", **change}, source="bad.yaml")


def test_person_box_holds_the_painted_person():
    people = [standing(1, 4.0, 0.5, appearance={"shirt_rgb": GREEN, "pattern": "plain"})]
    sim = Simulation(scenario(people=people))
    img = sim.image_pixels()
    bg = Simulation(scenario()).image_pixels()
    ys, xs = np.nonzero(np.any(img != bg, axis=2))
    st = sim.people_states()[0]
    x0, y0, x1, y1 = sim.camera.person_box(sim.robot.pose, sim.robot.pan_rad, st, sim.appearance(1))
    assert x0 - 1 <= xs.min() and xs.max() <= x1 + 1
    assert y0 - 1 <= ys.min() and ys.max() <= y1 + 1
    # and it is tight: the painted person spans most of it
    assert (xs.max() - xs.min()) > 0.6 * (x1 - x0) and (ys.max() - ys.min()) > 0.9 * (y1 - y0)
