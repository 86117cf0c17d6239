import math

import numpy as np
import pytest

from followbot.services.sim.scenario import load_builtin
from followbot.services.sim.simulation import Simulation

from .helpers import scenario, standing


def test_truth_frames_are_consistent():
    sim = Simulation(
        scenario(
            robot={"start": [1.0, -1.0], "yaw_deg": 40.0},
            people=[
                standing(1, 3.0, 1.0, is_target=True),
                {"id": 2, "start": [2.0, -2.0], "path": [{"kind": "walk", "to": [5.0, -2.0]}]},
            ],
        )
    )
    sim.advance_to(1_000_000_000)
    truth = sim.truth()
    assert truth.target_id == 1
    yaw = math.radians(40.0)
    for p in truth.people:
        dx, dy = p.x_m - 1.0, p.y_m + 1.0
        assert p.robot_x_m == pytest.approx(math.cos(yaw) * dx + math.sin(yaw) * dy)
        assert p.robot_y_m == pytest.approx(-math.sin(yaw) * dx + math.cos(yaw) * dy)
        legs = np.array(p.legs_robot_m).reshape(2, 2)
        assert legs.mean(axis=0) == pytest.approx([p.robot_x_m, p.robot_y_m], abs=0.2)
    walker = truth.people[1]
    assert math.hypot(walker.vx_mps, walker.vy_mps) == pytest.approx(0.6)
    assert math.hypot(walker.robot_vx_mps, walker.robot_vy_mps) == pytest.approx(0.6)
    assert [p.is_target for p in truth.people] == [True, False]


def test_occlusion_pillar_hides_the_target_twice_for_about_two_seconds():
    sim = Simulation(load_builtin("occlusion_pillar"))  # no controller: the robot stands
    hidden, start = [], None
    while sim.t_s < sim.scenario.duration_s - 0.2:
        for msg in sim.tick():
            if type(msg).__name__ == "GroundTruth":
                seen = msg.people[0].visible_laser
                if not seen and start is None:
                    start = sim.t_s
                elif seen and start is not None:
                    hidden.append(sim.t_s - start)
                    start = None
    assert start is None  # visible at the end
    assert hidden == [pytest.approx(2.0, abs=0.2)] * 2


def test_occlusion_scenario_hides_the_target_from_the_laser():
    sim = Simulation(load_builtin("livingston_box_occlusion"))
    seen = []
    while sim.t_s < 30.0:
        for msg in sim.tick():
            if type(msg).__name__ == "GroundTruth":
                seen.append(msg.people[0].visible_laser)
    assert any(seen) and not all(seen)


def _walk_through_robot(clearance):
    robot = {"start": [0.0, 0.0]} if clearance == "default" else {"people_clearance_m": clearance}
    sim = Simulation(
        scenario(
            robot=robot,
            people_spacing_m=None,  # the robot alone here
            people=[
                {
                    "id": 1,
                    "start": [2.0, 0.05],
                    "heading_deg": 180.0,
                    "path": [{"kind": "walk", "to": [-2.0, 0.05]}],
                },
                standing(2, 0.1, 0.0),  # standing on the robot's centre, almost
            ],
        )
    )
    track, stood = [], []
    while sim.t_s < 7.5:
        sim.step(20_000_000)
        states = sim.people_states()
        track.append(states[0])
        stood.append(states[1].position.copy())
    return sim, track, stood


def test_people_give_way_to_the_robot_and_rejoin_their_script():
    sim, track, stood = _walk_through_robot("default")
    c = sim.scenario.robot.radius_m + sim.scenario.robot.people_clearance_m
    pos = np.array([s.position for s in track])
    dist = np.hypot(pos[:, 0], pos[:, 1])
    assert dist.min() >= c - 1e-9  # never inside the clearance
    assert pos[:, 1].max() == pytest.approx(c, abs=0.01)  # round it on its own (left) side
    assert (pos[:, 1] > 0.05 - 1e-9).all()  # never crosses to the other side
    step = np.hypot(*np.diff(pos, axis=0).T)
    assert step.max() < 0.6 * 0.02 * 1.3  # no jump: a smooth swerve (<= 0.63 m sideways per m)
    assert pos[-1] == pytest.approx([-2.0, 0.05], abs=1e-9)  # back on the script
    for s in track:  # the legs move with the body
        assert s.legs.mean(axis=0) == pytest.approx(s.position, abs=0.2)
    assert all(np.hypot(*p) == pytest.approx(c) for p in stood)  # pushed out radially


def test_people_walk_through_the_robot_when_giving_way_is_off():
    _, track, stood = _walk_through_robot(None)
    pos = np.array([s.position for s in track])
    assert np.hypot(pos[:, 0], pos[:, 1]).min() == pytest.approx(0.05, abs=0.02)
    assert stood[0] == pytest.approx([0.1, 0.0])


def _crossing(spacing):
    extra = {} if spacing == "default" else {"people_spacing_m": spacing}
    sim = Simulation(
        scenario(
            robot={"start": [-5.0, 5.0]},  # out of the way
            **extra,
            people=[
                {
                    "id": 1,
                    "start": [2.0, 0.0],
                    "heading_deg": 180.0,
                    "path": [{"kind": "walk", "to": [-2.0, 0.0]}],
                },
                {
                    "id": 2,
                    "start": [-2.0, 0.1],
                    "heading_deg": 0.0,
                    "path": [{"kind": "walk", "to": [2.0, 0.1]}],
                },
                standing(3, 0.0, -2.0),
                standing(4, 0.0, -2.0),  # scripted on the same spot as 3
            ],
        )
    )
    out = []
    while sim.t_s < 7.5:
        sim.step(20_000_000)
        out.append([s.position.copy() for s in sim.people_states()])
    return sim, np.array(out)


def test_people_give_way_to_each_other():
    sim, pos = _crossing("default")
    c = sim.scenario.people_spacing_m
    gap = np.hypot(*(pos[:, 0] - pos[:, 1]).T)
    assert gap.min() >= c - 1e-9  # the walkers pass at a shoulder width at least
    step = np.hypot(*np.diff(pos[:, :2], axis=0).transpose(2, 0, 1))
    assert step.max() < 0.6 * 0.02 * 1.3  # smoothly
    assert pos[-1, 0] == pytest.approx([-2.0, 0.0])  # and each back on the script
    assert pos[-1, 1] == pytest.approx([2.0, 0.1])
    assert np.hypot(*(pos[:, 2] - pos[:, 3]).T).min() == pytest.approx(c)  # one spot: apart
    # each steps half the way: the middle of the pair stays where the scripts put it
    assert (pos[:, 2] + pos[:, 3]) / 2 == pytest.approx(np.tile([0.0, -2.0], (len(pos), 1)))


def test_people_walk_through_each_other_when_spacing_is_off():
    _, pos = _crossing(None)
    assert np.hypot(*(pos[:, 0] - pos[:, 1]).T).min() == pytest.approx(0.1, abs=0.02)
    assert (pos[:, 2] == pos[:, 3]).all()
