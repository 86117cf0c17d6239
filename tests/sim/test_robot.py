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


def _wall_ahead(**robot):
    """A wall across the robot's way 2 m ahead (x = 2), the robot at the origin facing it."""
    return scenario(
        world={"walls": [{"points": [[2.0, -3.0], [2.0, 3.0]]}]},
        robot={"odometry": {"noise": False}, **robot},
    )


def test_the_bumper_stops_the_base_at_a_wall_and_counts_the_contact_once():
    sim = Simulation(_wall_ahead())
    _drive(sim, 0.75, 0.0, 6.0)
    x = sim.robot.pose[0]
    # the 0.25 m disc stops against the wall (within one 5 ms step of travel), not through it
    assert 2.0 - 0.25 - 0.004 <= x < 2.0 - 0.25
    assert sim.robot.v_mps == 0.0
    assert sim.robot.bumps == 1
    assert sim.truth().robot_bumps == 1
    # odometry saw the base stop too (the wheels do not turn against the wall)
    assert sim.odometry().x_m == pytest.approx(x, abs=1e-9)


def test_against_the_wall_the_base_still_turns_and_backs_away_but_does_not_slide_into_it():
    sim = Simulation(_wall_ahead())
    _drive(sim, 0.75, 0.0, 6.0)
    x0 = sim.robot.pose[0]
    _drive(sim, 0.0, 1.0, 0.5)  # turning on the spot: free
    assert sim.robot.pose[0] == pytest.approx(x0)
    assert sim.robot.pose[2] != pytest.approx(0.0)
    _drive(sim, 0.5, 0.0, 0.5)  # heading ~30 deg into the wall: still blocked
    assert sim.robot.pose[0] == pytest.approx(x0, abs=1e-6)
    _drive(sim, 0.0, -2.0, 2.5)  # turn round (limited to 100 deg/s) ...
    _drive(sim, 0.5, 0.0, 1.0)  # ... and away: free, and a new contact later counts anew
    assert sim.robot.pose[0] < x0 - 0.2
    assert sim.robot.bumps == 1


def test_the_bumper_knows_circles_and_boxes_and_can_be_switched_off():
    world = {
        "circles": [{"centre": [1.5, 0.0], "radius_m": 0.1}],
        "boxes": [{"centre": [0.0, 1.5], "size_m": [1.0, 0.4]}],
    }
    sim = Simulation(scenario(world=world))
    _drive(sim, 0.75, 0.0, 4.0)
    assert sim.robot.pose[0] == pytest.approx(1.5 - 0.1 - 0.25, abs=0.004)
    sim = Simulation(scenario(world=world, robot={"yaw_deg": 90.0, "odometry": {"noise": False}}))
    _drive(sim, 0.75, 0.0, 4.0)
    assert sim.robot.pose[1] == pytest.approx(1.5 - 0.2 - 0.25, abs=0.004)
    off = Simulation(scenario(world=world, robot={"bumper": False, "odometry": {"noise": False}}))
    _drive(off, 0.75, 0.0, 4.0)
    assert off.robot.pose[0] > 2.0 and off.robot.bumps == 0
    assert off.truth().robot_bumps == 0


def test_a_robot_started_against_a_wall_may_drive_away():
    sim = Simulation(_wall_ahead(start=[1.85, 0.0], yaw_deg=180.0))
    _drive(sim, 0.5, 0.0, 1.0)
    assert sim.robot.pose[0] < 1.5 and sim.robot.bumps == 0
