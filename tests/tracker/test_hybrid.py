"""Seed 001 3.3 and 4: the hybrid particle filter (particles for position, Kalman filter for
size), its MAP output, and its prediction between image planes of a moving camera."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.services.runtime.ground_plane import GroundCamera
from followbot.services.tracker.estimators.hybrid import HybridFilter, HybridSettings


def rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def test_a_region_walking_right_to_left_is_followed_by_the_map_particle():
    f = HybridFilter(np.array([280.0, 150.0, 30.0, 90.0]), None, np.random.default_rng(0))
    errors = []
    for k in range(1, 60):
        x = 280.0 - 4.0 * k  # 40 px/s at 10 frames/s
        f.step(np.array([[x, 150.0, 30.0, 90.0]]), 0.1)
        errors.append(abs(f.position[0] - x))
    assert max(errors[10:]) < 8.0
    assert f.position[2] == pytest.approx(-40.0, abs=15.0)  # the velocity was learnt


def test_the_output_is_the_map_particle_not_the_weighted_mean():
    f = HybridFilter(np.array([160.0, 150.0, 30.0, 90.0]), None, np.random.default_rng(1))
    # spread the cloud over two same-sized regions 80 px apart
    f.particles[:, 0] = np.random.default_rng(2).uniform(100, 220, len(f.particles))
    regions = np.array([[120.0, 150.0, 30.0, 90.0], [200.0, 150.0, 30.0, 90.0]])
    f.update(regions)
    mean_x = float(f.weights @ f.particles[:, 0])
    nearest_region = min(abs(f.position[0] - 120.0), abs(f.position[0] - 200.0))
    assert nearest_region < 5.0  # on a region ...
    assert abs(mean_x - 160.0) < abs(f.position[0] - 160.0)  # ... where the mean falls between


def test_the_size_filter_takes_the_region_nearest_the_map_and_ignores_other_sizes():
    f = HybridFilter(np.array([160.0, 150.0, 30.0, 90.0]), None, np.random.default_rng(3))
    for _ in range(20):
        # the target at 160 grows; a same-coloured wall patch far larger sits at 60
        f.step(np.array([[160.0, 150.0, 34.0, 100.0], [60.0, 120.0, 120.0, 200.0]]), 0.1)
    assert f.size == pytest.approx([34.0, 100.0], abs=3.0)
    assert abs(f.position[0] - 160.0) < 6.0


def test_no_region_of_the_targets_size_is_a_miss_and_the_estimate_coasts():
    f = HybridFilter(np.array([160.0, 150.0, 30.0, 90.0]), None, np.random.default_rng(4))
    assert f.step(np.array([[150.0, 150.0, 30.0, 90.0]]), 0.1)
    assert not f.step(np.array([[160.0, 150.0, 200.0, 20.0]]), 0.1)
    assert not f.step(np.zeros((0, 4)), 0.1)
    assert abs(f.position[0] - 150.0) < 20.0


@pytest.mark.parametrize("elevation_deg", [0.0, -10.0])
def test_a_standing_person_stays_put_in_the_world_while_the_robot_turns_and_drives(
    elevation_deg,
):
    """Seed 4, figure 3: with the image-plane prediction through the floor, a person standing
    still needs no correction as the robot moves; measurements are withheld, so the filter
    runs on the prediction alone."""
    cam = GroundCamera(height_m=0.6, elevation_deg=elevation_deg)
    person = np.array([4.0, 0.5])  # world frame; the robot starts at the origin facing +x
    settings = HybridSettings(camera=cam, q_xy=1e-6, q_wh=1e-6)

    def box(pose):
        x, y, yaw = pose
        rel = rot(-yaw) @ (person - [x, y])
        u, v = cam.floor_to_pixel(rel[0], rel[1])
        h = cam.focal_px * 0.8 / np.hypot(*rel)  # 0.8 m of trousers
        return np.array([float(u), float(v) - h / 2, h / 3, h])

    pose = (0.0, 0.0, 0.0)
    f = HybridFilter(box(pose), settings, np.random.default_rng(5))
    for _ in range(25):  # drive forward while turning left
        new = (
            pose[0] + 0.08 * math.cos(pose[2]),
            pose[1] + 0.08 * math.sin(pose[2]),
            pose[2] + 0.03,
        )
        # base-frame change: p_new = R(-dyaw) (p_old - dt_xy_in_old_frame)
        d = rot(-pose[2]) @ np.array([new[0] - pose[0], new[1] - pose[1]])
        r = rot(-(new[2] - pose[2]))
        f.resample()
        f.ego_motion(r, -r @ d)
        f.predict(1e-6)
        pose = new
        fx, fy = f.floor_point()
        world = rot(pose[2]) @ [fx, fy] + pose[:2]
        assert np.hypot(*(world - person)) < 0.02
        assert f.box == pytest.approx(box(pose), abs=0.5)
