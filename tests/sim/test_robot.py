import math

import pytest

from followbot.services.sim.simulation import Simulation

from .helpers import scenario


def _drive(sim, v, w, seconds, every_ns=100_000_000):
    end = sim.t_ns + round(seconds * 1e9)
    while sim.t_ns < end:
        sim.command_velocity(v, w)
        sim.advance_to(min(end, sim.t_ns + every_ns))


def test_commanded_velocity_gives_the_expected_odometry():
    sim = Simulation(scenario())
    _drive(sim, 0.5, 0.0, 3.0)
    # accelerate at 1 m/s^2 to 0.5 m/s (0.5 s, 0.125 m), then 2.5 s at 0.5 m/s
    odom = sim.odometry()
    assert odom.x_m == pytest.approx(0.125 + 1.25, abs=0.003)
    assert odom.y_m == pytest.approx(0.0, abs=1e-12)
    assert odom.v_mps == pytest.approx(0.5)


def test_arc_odometry_equals_the_true_motion_without_noise():
    sim = Simulation(scenario(robot={"start": [1.0, 2.0], "yaw_deg": 30.0}))
    _drive(sim, 0.4, 0.8, 4.0)
    odom, (x, y, yaw) = sim.odometry(), sim.robot.pose
    # odom starts at (0, 0, 0) on the start pose: rotate the true displacement into it
    th0 = math.radians(30.0)
    dx, dy = x - 1.0, y - 2.0
    assert odom.x_m == pytest.approx(math.cos(th0) * dx + math.sin(th0) * dy, abs=1e-9)
    assert odom.y_m == pytest.approx(-math.sin(th0) * dx + math.cos(th0) * dy, abs=1e-9)
    assert math.remainder(odom.yaw_rad - (yaw - th0), 2 * math.pi) == pytest.approx(0, abs=1e-9)
    # steady state: a circle of radius v / w = 0.5 m, so it came back near the start area
    assert math.hypot(dx, dy) < 1.0 + 1e-9


def test_speed_and_turn_limits():
    sim = Simulation(scenario())
    _drive(sim, 3.0, 10.0, 2.0)
    assert sim.robot.v_mps == pytest.approx(0.75)  # thesis: 750 mm/s
    assert sim.robot.w_radps == pytest.approx(math.radians(100))  # thesis: 100 deg/s


def test_watchdog_stops_a_robot_without_commands():
    sim = Simulation(scenario())
    _drive(sim, 0.5, 0.0, 1.0)
    sim.advance_to(sim.t_ns + 2_000_000_000)
    assert sim.robot.v_mps == 0.0


def test_pan_unit_rate_and_range():
    sim = Simulation(scenario())
    sim.command_pan(math.radians(150))
    sim.advance_to(500_000_000)
    assert sim.robot.pan_rad == pytest.approx(math.radians(45))  # 90 deg/s
    sim.advance_to(2_000_000_000)
    assert sim.robot.pan_rad == pytest.approx(math.radians(100))  # +-100 deg


def test_odometry_noise_makes_drift_accumulate():
    sc = scenario(robot={"odometry": {"noise": True, "slip_std": 0.02}})
    sim = Simulation(sc, seed=4)
    errors = []
    for _ in range(4):
        _drive(sim, 0.6, 0.3, 5.0)
        odom, (x, y, _) = sim.odometry(), sim.robot.pose
        errors.append(math.hypot(odom.x_m - x, odom.y_m - y))
    assert errors[-1] > errors[0] > 0.0
    assert errors[-1] < 0.1 * 0.6 * 20  # a few percent of the distance, not nonsense


def test_non_finite_commands_are_refused():
    sim = Simulation(scenario())
    with pytest.raises(ValueError):
        sim.command_velocity(math.nan, 0.0)
    with pytest.raises(ValueError):
        sim.command_pan(math.inf)
