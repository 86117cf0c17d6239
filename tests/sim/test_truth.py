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


def test_occlusion_scenario_hides_the_target_from_the_laser():
    sim = Simulation(load_builtin("livingston_box_occlusion"))
    seen = []
    while sim.t_s < 30.0:
        for msg in sim.tick():
            if type(msg).__name__ == "GroundTruth":
                seen.append(msg.people[0].visible_laser)
    assert any(seen) and not all(seen)
