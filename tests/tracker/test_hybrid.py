"""Seed 001 3.3 and 4: the hybrid particle filter (particles for position, Kalman filter for
size), its MAP output, and its prediction between image planes of a moving camera."""

from __future__ import annotations

import math

import msgspec
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
    settings = HybridSettings(camera=cam, q_x=1e-6, q_y=1e-6, q_wh=1e-6)

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


# --------------------------------------------------------------------------- as an estimator


def _run_tracker_on_camera(name: str, drive, seconds: float):
    """The simulator's frames -> camera_blobs' candidates (answer per scan, newest frame) ->
    the tracker with estimator ``hybrid``; ``drive(t)`` gives the robot's (v, w). Yields
    (truth, target state) per scan."""
    from followbot.schemas import Image, LaserScan, Odometry, PersonCandidates
    from followbot.services.camera_blobs.node import BlobFinder, CameraBlobsSettings, _Frame
    from followbot.services.runtime.mount import LaserMount
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation
    from followbot.services.tracker.core import Tracker, TrackerSettings

    sim = Simulation(load_builtin(name))
    cs = sim.scenario.camera
    cam = GroundCamera(width=cs.width, height=cs.height, hfov_deg=cs.hfov_deg, height_m=cs.height_m)
    tracker = Tracker(
        TrackerSettings(
            estimator="hybrid", estimator_settings={"camera": msgspec.to_builtins(cam)},
            acquire="nearest",
        )
    )  # fmt: skip
    finder = frame = None
    while not sim.finished and sim.next_tick_ns / 1e9 < seconds:
        t = sim.next_tick_ns / 1e9
        sim.command_velocity(*drive(t))
        for msg in sim.tick():
            if isinstance(msg, Odometry):
                tracker.add_odometry(msg)
            elif isinstance(msg, Image):
                if finder is None:  # the user's rectangle on the target's trousers
                    truth = sim.truth()
                    tg = next(p for p in truth.people if p.is_target)
                    u, v = cam.floor_to_pixel(tg.robot_x_m, tg.robot_y_m)
                    d = math.hypot(tg.robot_x_m, tg.robot_y_m)
                    f = cam.focal_px
                    rect = [
                        float(u) - f * 0.05 / d,
                        float(v) - f * 0.4 / d,
                        f * 0.1 / d,
                        f * 0.3 / d,
                    ]
                    finder = BlobFinder(CameraBlobsSettings(learn_rect=rect, camera=cam))
                boxes = finder.regions_of(msg.pixels())
                frame = _Frame(msg.stamp_ns, msg.pan_rad, msg.width, msg.height, boxes)
            elif isinstance(msg, LaserScan) and frame is not None:
                cands = PersonCandidates(
                    stamp_ns=msg.stamp_ns, frame_id="laser",
                    candidates=finder.candidates(frame, LaserMount()),
                    image_stamp_ns=frame.stamp_ns, image_width=frame.width,
                )  # fmt: skip
                state, _ = tracker.step(cands)
                yield sim.truth(), state


def test_the_tracker_with_the_hybrid_estimator_reports_the_target_where_it_stands():
    """Through the tracker: bearing as exact as the image column, range as good as a camera
    0.4 m high reads it from the region's bottom edge (~0.1 m per pixel at 3.5 m)."""

    # the robot turns to and fro on the spot, then drives while the target walks away
    def drive(t):
        return (0.3, 0.0) if t > 4.0 else (0.0, 0.2 * math.sin(2 * t))

    bearing_deg, range_rel, scans = [], [], 0
    for truth, state in _run_tracker_on_camera("zhuang_corridor", drive, 10.0):
        scans += 1
        tg = next(p for p in truth.people if p.is_target)
        if state.status == "tracking":
            off = math.atan2(state.y_m, state.x_m) - math.atan2(tg.robot_y_m, tg.robot_x_m)
            bearing_deg.append(abs(math.degrees(off)))
            true_r = math.hypot(tg.robot_x_m, tg.robot_y_m)
            range_rel.append(abs(math.hypot(state.x_m, state.y_m) / true_r - 1.0))
    assert len(bearing_deg) >= 0.9 * scans  # tracked from the 4th scan on
    assert max(bearing_deg) < 3.0
    assert float(np.percentile(range_rel, 90)) < 0.3
