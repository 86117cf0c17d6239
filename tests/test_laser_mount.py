"""The laser's mount on the base (laser_mount): the transforms, and the real pipeline with a
laser mounted off-centre and turned."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from followbot.schemas import Candidate, Leg, PersonCandidates
from followbot.services.runtime.mount import (
    BASE_FRAME,
    LaserMount,
    candidates_in_base,
    parse_laser_pose,
)
from followbot.services.runtime.settings import NodeSettings, SettingsError, load_settings

MOUNT = LaserMount(x_m=0.5, y_m=-0.2, yaw_deg=40.0)
LASER = {"mount_x_m": 0.5, "mount_y_m": -0.2, "mount_yaw_deg": 40.0}


def test_laser_and_base_frames_are_each_other_s_inverse():
    rng = np.random.default_rng(1)
    p = rng.uniform(-5, 5, (20, 2))
    assert MOUNT.to_laser(MOUNT.to_base(p)) == pytest.approx(p)
    # the laser's own origin is the mount point; its +x axis points 40 deg left of the base's
    assert MOUNT.to_base([0.0, 0.0])[0] == pytest.approx([0.5, -0.2])
    ahead = MOUNT.to_base([1.0, 0.0])[0] - MOUNT.to_base([0.0, 0.0])[0]
    assert math.degrees(math.atan2(ahead[1], ahead[0])) == pytest.approx(40.0)
    assert LaserMount().is_identity and not MOUNT.is_identity


def test_candidates_are_turned_into_the_base_frame_with_their_range_and_bearing():
    legs = [
        Leg(x_m=2.0, y_m=0.1, first_beam=0, last_beam=2),
        Leg(x_m=2.0, y_m=-0.1, first_beam=4, last_beam=6),
    ]
    cand = Candidate(x_m=2.0, y_m=0.0, range_m=2.0, bearing_rad=0.0, legs=legs)
    msg = PersonCandidates(stamp_ns=1, frame_id="laser", n_beams=10, candidates=[cand])
    out = candidates_in_base(msg, MOUNT)
    c = out.candidates[0]
    x, y = MOUNT.to_base([2.0, 0.0])[0]
    assert (c.x_m, c.y_m) == pytest.approx((x, y))
    assert c.range_m == pytest.approx(math.hypot(x, y))
    assert c.bearing_rad == pytest.approx(math.atan2(y, x))
    moved = [[leg.x_m, leg.y_m] for leg in c.legs]
    assert np.allclose(moved, MOUNT.to_base([[2.0, 0.1], [2.0, -0.1]]))
    assert out.frame_id == BASE_FRAME and msg.candidates[0].x_m == 2.0  # a copy
    same = candidates_in_base(msg, LaserMount())
    assert same.candidates == msg.candidates and same.frame_id == BASE_FRAME


def test_the_laser_pose_option_reads_x_y_and_degrees_and_says_its_form_when_wrong():
    assert parse_laser_pose("0.88, 0, 42") == LaserMount(x_m=0.88, y_m=0.0, yaw_deg=42.0)
    for bad in ("0.88,0", "a,b,c", "0,0,nan", "0,0,720"):
        with pytest.raises(ValueError, match="expected x,y,yaw_deg"):
            parse_laser_pose(bad)


def test_laser_mount_is_a_setting_of_every_service_checked_when_it_loads(tmp_path):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("laser_mount: {x_m: 0.88, yaw_deg: 42}\n")
    assert load_settings(NodeSettings, cfg).laser_mount == LaserMount(x_m=0.88, yaw_deg=42.0)
    cfg.write_text("laser_mount: {x: 0.88}\n")
    with pytest.raises(SettingsError, match="laser_mount"):
        load_settings(NodeSettings, cfg)


def test_a_compose_file_s_laser_mount_reaches_every_service(tmp_path):
    from followbot.services.runtime.compose import load_compose, service_settings

    f = tmp_path / "c.yaml"
    f.write_text(
        "laser_mount: {x_m: 0.88, y_m: 0, yaw_deg: 42}\n"
        "services: {laser_legs: {}, tracker: {process: core}, controller: {process: core}}\n"
    )
    compose = load_compose(f)
    for name in ("laser_legs", "tracker", "controller"):
        assert service_settings(compose, name)["laser_mount"] == {
            "x_m": 0.88,
            "y_m": 0,
            "yaw_deg": 42,
        }


def test_the_simulator_refuses_a_laser_mount_that_is_not_its_scenario_s(tmp_path):
    from followbot.services.sim.node import SimSettings, check

    scenario = _standing_scenario(tmp_path)
    with pytest.raises(ValueError, match=r"its laser sits at x 0\.500 m, y -0\.200 m, yaw 40\.0"):
        check(SimSettings(scenario=str(scenario)))
    check(SimSettings(scenario=str(scenario), laser_mount=MOUNT))


def _standing_scenario(tmp_path, duration_s: float = 8.0):
    """One person standing 2.6 m ahead and 1.6 m left of the robot; the laser 0.5 m ahead,
    0.2 m right of the base's centre and turned 40 deg left. The controller turns the robot
    towards the person and drives up to them."""
    spec = {
        "name": "mounted_laser",
        "duration_s": duration_s,
        "seed": 3,
        "world": {"walls": [{"points": [[-3, -4], [8, -4], [8, 6], [-3, 6]], "closed": True}]},
        "laser": LASER,
        "people": [{"id": 1, "is_target": True, "start": [2.6, 1.6], "heading_deg": 180.0}],
    }
    path = tmp_path / "mounted_laser.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def _world_errors(run) -> tuple[list[float], float, float]:
    """Per scan with the target tracked: how far the tracker's estimate (base frame), mapped to
    the world by the robot's true pose, lies from where the person stands; and how far the
    robot drove and turned."""
    errors = []
    for r in run.records:
        t = r.target
        if t is None or t.status != "tracking":
            continue
        g = r.truth
        c, s = math.cos(g.robot_yaw_rad), math.sin(g.robot_yaw_rad)
        wx = g.robot_x_m + c * t.x_m - s * t.y_m
        wy = g.robot_y_m + s * t.x_m + c * t.y_m
        person = next(p for p in g.people if p.is_target)
        errors.append(math.hypot(wx - person.x_m, wy - person.y_m))
    first, last = run.records[0].truth, run.records[-1].truth
    driven = math.hypot(last.robot_x_m - first.robot_x_m, last.robot_y_m - first.robot_y_m)
    turned = abs(math.degrees(last.robot_yaw_rad - first.robot_yaw_rad))
    return errors, driven, turned


@pytest.mark.parametrize("stages_told", [True, False], ids=["mount_given", "mount_not_given"])
def test_a_standing_person_stays_still_in_the_world_with_the_laser_off_centre_and_turned(
    tmp_path, stages_told
):
    """The real pipeline (sim, laser_legs, tracker, controller: one process each, lock-step):
    the robot turns towards a standing person and drives up to them. With laser_mount given
    (followbot eval passes the scenario's), the tracker's estimate stays within 0.2 m of where
    the person stands in the world the whole way (the detector's person centre alone is off by
    up to ~0.15 m, with a laser at the base's centre too: 0.13 m median there, 0.08 m here).
    The control: the stages told the laser sits at the base's centre, facing ahead (the sim's
    laser unchanged), place the person 0.5-1.6 m off, moving as the robot turns."""
    from followbot.runner import run_scenario

    scenario = _standing_scenario(tmp_path)
    wrong = "laser_mount={x_m: 0, y_m: 0, yaw_deg: 0}"
    overrides = [] if stages_told else [f"{s}.{wrong}" for s in ("laser_legs", "tracker")]
    run = run_scenario(
        str(scenario), "thesis", tmp_path / "run", vision=False, progress=False, record=False,
        overrides=overrides,
    )  # fmt: skip
    assert not any(run.timeouts.values()), run.timeouts
    errors, driven, turned = _world_errors(run)
    assert len(errors) > 0.8 * len(run.records)  # tracked nearly throughout
    if stages_told:
        assert driven > 0.8 and turned > 15.0, (driven, turned)  # it drove and turned
        assert max(errors) < 0.2, errors
    else:
        assert min(errors) > 0.3 and max(errors) - min(errors) > 0.5, errors
