"""Seed 001 equations 15-16: pixel <-> floor point, both ways and against the simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.services.runtime.ground_plane import GroundCamera


def printed_15_16(cam: GroundCamera, xp: float, yp: float) -> tuple[float, float]:
    """Equations 15-16 exactly as the seed prints them (f_cx = f_cy here)."""
    f, (cx, cy) = cam.focal_px, cam.centre
    a, h = math.radians(cam.elevation_deg), cam.height_m
    xr = (f * h * math.cos(a) + h * math.sin(a) * (yp - cy)) / (
        (yp - cy) * math.cos(a) - f * math.sin(a)
    )
    yr = (xp - cx) * (h * math.sin(a) - xr * math.cos(a)) / f
    return xr, yr


@pytest.mark.parametrize("elevation_deg", [-25.0, -8.0, 0.0, 5.0])
def test_pixel_to_floor_is_the_seeds_equations(elevation_deg):
    cam = GroundCamera(elevation_deg=elevation_deg, height_m=0.9)
    for xp, yp in [(10.0, 239.0), (160.0, 200.0), (300.0, 180.0)]:
        fx, fy = cam.pixel_to_floor(xp, yp)
        assert (float(fx), float(fy)) == pytest.approx(printed_15_16(cam, xp, yp))


@pytest.mark.parametrize("elevation_deg", [-30.0, -10.0, 0.0, 8.0])
@pytest.mark.parametrize("pan_rad", [0.0, 0.4])
def test_pixel_floor_pixel_round_trip(elevation_deg, pan_rad):
    cam = GroundCamera(elevation_deg=elevation_deg, height_m=1.2, mount_x_m=0.2)
    rng = np.random.default_rng(1)
    horizon = cam.centre[1] + cam.focal_px * math.tan(math.radians(elevation_deg))
    u = rng.uniform(0, cam.width, 200)
    v = rng.uniform(max(horizon + 2.0, 0.0), cam.height, 200)
    fx, fy = cam.pixel_to_floor(u, v, pan_rad)
    assert np.isfinite(fx).all()
    u2, v2 = cam.floor_to_pixel(fx, fy, pan_rad)
    np.testing.assert_allclose(u2, u, atol=1e-6)
    np.testing.assert_allclose(v2, v, atol=1e-6)


def test_floor_pixel_floor_round_trip():
    cam = GroundCamera(elevation_deg=-12.0)
    x = np.linspace(1.0, 8.0, 30)
    y = np.linspace(-1.5, 1.5, 30)
    u, v = cam.floor_to_pixel(x, y)
    fx, fy = cam.pixel_to_floor(u, v)
    np.testing.assert_allclose(fx, x, atol=1e-9)
    np.testing.assert_allclose(fy, y, atol=1e-9)


def test_pixels_above_the_horizon_and_points_behind_have_no_answer():
    cam = GroundCamera()  # level: the horizon is the middle row
    fx, fy = cam.pixel_to_floor(np.array([100.0, 100.0]), np.array([120.0, 50.0]))
    assert np.isnan(fx).all() and np.isnan(fy).all()
    u, v = cam.floor_to_pixel(np.array([-1.0]), np.array([0.0]))
    assert np.isnan(u).all() and np.isnan(v).all()


def test_the_simulators_camera_draws_a_floor_point_where_the_equations_put_it():
    from followbot.services.sim.camera import CameraModel
    from followbot.services.sim.scenario import CameraSpec, WorldSpec
    from followbot.services.sim.world import StaticWorld

    spec = CameraSpec(noise_std=0, height_m=1.1, mount_x_m=0.15)
    sim = CameraModel(spec, StaticWorld.from_spec(WorldSpec()), np.random.default_rng(0))
    cam = GroundCamera(height_m=1.1, mount_x_m=0.15, hfov_deg=spec.hfov_deg)
    for x, y, pan in [(2.0, 0.3, 0.0), (3.5, -1.0, -0.2), (1.5, 0.6, 0.5)]:
        xc, yc = sim.to_camera(sim.camera_pose((0.0, 0.0, 0.0), pan), np.array([x, y]))
        u_sim, v_sim = sim.column(xc, yc), sim.row(xc, 0.0)
        u, v = cam.floor_to_pixel(x, y, pan)
        assert (float(u), float(v)) == pytest.approx((u_sim, v_sim))
        fx, fy = cam.pixel_to_floor(u_sim, v_sim, pan)
        assert (float(fx), float(fy)) == pytest.approx((x, y))


def test_bad_cameras_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="above the floor"):
        GroundCamera(height_m=0.0)
    with pytest.raises(ValueError, match="elevation_deg"):
        GroundCamera(elevation_deg=95.0)
