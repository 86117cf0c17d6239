"""Seed 001's hybrid particle filter (Zhuang et al. 3.3, 4): a person in the image plane.

The state splits in two (equation 10): the position part S = [x, y, vx, vy] (pixels, px/s; the
centre of the target's rectangle) is a particle filter of ``particles`` samples (150, seed 5.1);
the shape part B = [w, h, dw, dh] (the rectangle's size and its rate of change) is a Kalman
filter (filterpy's KalmanFilter). Both move by the near-constant-velocity model of equation 11
with the white-acceleration noise of Q11 / Q22:

    Phi' = [[I2, dt I2], [O2, I2]]
    Q11  = [[dt^3/3 q, dt^2/2 q], [dt^2/2 q, dt q]],  q = diag(q_x, q_y)    (Q22: q_w, q_h)

One step (seed 3.3.2, steps 1-6), given the regions Z_j = [x, y, w, h] of the frame:

1. resample the particles by their last weights (with replacement);
2. predict each particle by Phi' plus noise drawn from Q11; predict the Kalman filter;
3. the predicted measurements: each particle's (x, y), the filter's (w, h);
4. weights: keep the regions whose size is within ``shape_gate`` (Mahalanobis, chi-square 2
   dof) of the predicted (w, h); each particle takes the kept region nearest to it (Euclidean)
   and is weighted by the 2-D Gaussian of equation 14 with R = diag(sigma_x^2, sigma_y^2); the
   output position is the MAP particle (the one of largest weight), not the weighted mean;
5. the Kalman filter is updated with the kept region nearest the MAP particle;
6. the estimate is [S_MAP, B].

Moving camera (seed 4, figure 3). Between two frames the robot moves, so the image plane
moves: each particle's foot point (x, y + h/2) -- the bottom of the rectangle, the point on
the floor -- goes through equations 15-16 (services/runtime/ground_plane.py) to the floor in
the old base frame, is moved by the robot's motion (p1 = R p0 + t, from odometry), and is
projected into the new image; the rectangle's size scales with the depth ratio. The person's
own motion is then the particles' velocity (step 2). The seed projects the rectangle's centre
through equations 15-16; the centre of a person's legs is ~0.4 m above the floor, so its floor
point would be ~1.7x too far at 1 m camera height. The bottom edge is what stands on the floor.

Seed errata kept here: step 4 cites "(16)" for the weights; it is equation (14). The seed gives
no noise values: the defaults below were chosen on the simulator (320x240 pixels, scaled by
the image width for other sizes).
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from followbot.services.runtime.ground_plane import GroundCamera

from .particle import systematic_resample

__all__ = ["HybridFilter", "HybridSettings"]

_REF_WIDTH = 320.0  # pixel settings are given for a 320 px wide image


class HybridSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    particles: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 150  # seed 5.1: 150 particles
    q_xy: Annotated[float, msgspec.Meta(gt=0)] = 4000.0
    """q_x = q_y of Q11: white acceleration spectral density, px^2/s^3 (at 320 px wide)."""
    q_wh: Annotated[float, msgspec.Meta(gt=0)] = 1000.0
    """q_w = q_h of Q22, px^2/s^3."""
    sigma_xy_px: Annotated[float, msgspec.Meta(gt=0)] = 8.0
    """sigma_x = sigma_y of R in equation 14 (the weight's Gaussian), px."""
    sigma_wh_px: Annotated[float, msgspec.Meta(gt=0)] = 6.0
    """sigma_w = sigma_h of R for the Kalman filter's measurement, px."""
    shape_gate: Annotated[float, msgspec.Meta(gt=0)] = 13.8
    """Mahalanobis gate on a region's size (chi-square, 2 dof: 13.8 keeps 99.9 %)."""
    camera: GroundCamera = msgspec.field(default_factory=GroundCamera)
    """The camera the rectangles come from (equations 15-16)."""


class HybridFilter:
    """Particles over [x, y, vx, vy] in pixels, a Kalman filter over [w, h, dw, dh]."""

    def __init__(
        self, region: np.ndarray, settings: HybridSettings | None, rng: np.random.Generator
    ) -> None:
        from filterpy.kalman import KalmanFilter

        s = self.settings = settings or HybridSettings()
        self.rng = rng
        self.scale = s.camera.width / _REF_WIDTH
        x, y, w, h = (float(v) for v in region)
        self.particles = np.zeros((s.particles, 4))
        self.particles[:, 0], self.particles[:, 1] = x, y
        self.weights = np.full(s.particles, 1.0 / s.particles)
        self.map_index = 0
        kf = self.kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([w, h, 0.0, 0.0])
        kf.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
        sig = s.sigma_wh_px * self.scale
        kf.R = np.eye(2) * sig**2
        kf.P = np.diag([sig**2, sig**2, (20 * self.scale) ** 2, (20 * self.scale) ** 2])
        self.measured = True
        self.kept = np.zeros((0, 4))

    # ------------------------------------------------------------------ outputs

    @property
    def position(self) -> np.ndarray:
        """S_MAP: (4,) [x, y, vx, vy] of the MAP particle, px and px/s."""
        return self.particles[self.map_index].copy()

    @property
    def size(self) -> np.ndarray:
        """(2,) [w, h] of the Kalman filter, px."""
        return self.kf.x[:2].copy()

    @property
    def box(self) -> np.ndarray:
        """(4,) [x, y, w, h]: the estimate's rectangle."""
        return np.concatenate([self.position[:2], self.size])

    def floor_point(self, pan_rad: float = 0.0) -> np.ndarray:
        """(2,) the base-frame floor point under the estimate (its rectangle's bottom centre);
        NaN when that is at or above the horizon."""
        x, y = self.position[:2]
        fx, fy = self.settings.camera.pixel_to_floor(x, y + self.size[1] / 2.0, pan_rad)
        return np.array([float(fx), float(fy)])

    # ------------------------------------------------------------------ the step

    def resample(self) -> None:
        """Step 1: N particles drawn by their weights, weights 1/N."""
        idx = systematic_resample(self.weights, self.rng)
        self.particles = self.particles[idx]
        self.weights = np.full(len(idx), 1.0 / len(idx))
        # the MAP particle has the largest weight, so it was drawn: follow it to its copy (a
        # step without measurement reports it, predicted)
        copies = np.flatnonzero(idx == self.map_index)
        self.map_index = int(copies[0]) if len(copies) else 0

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        """Seed 4, figure 3: carry every particle's foot point through the floor into the image
        plane after the robot moved by p1 = rotation @ p0 + translation (base frames)."""
        cam = self.settings.camera
        h = self.size[1]
        x, y = self.particles[:, 0], self.particles[:, 1] + h / 2.0
        fx, fy = cam.pixel_to_floor(x, y)
        ok = np.isfinite(fx)
        p1 = rotation @ np.stack([fx, fy]) + np.asarray(translation).reshape(2, 1)
        u, v = cam.floor_to_pixel(p1[0], p1[1])
        ok &= np.isfinite(u)
        # the rectangle's size goes with 1 / depth (camera frame)
        d0 = np.hypot(fx - cam.mount_x_m, fy)
        d1 = np.hypot(p1[0] - cam.mount_x_m, p1[1])
        ratio = np.where(ok, d0 / np.where(ok, d1, 1.0), 1.0)
        self.particles[ok, 0] = u[ok]
        self.particles[ok, 1] = v[ok] - h * ratio[ok] / 2.0
        if ok.any():
            k = float(np.median(ratio[ok]))
            self.kf.x[:2] *= k
            self.kf.x[2:] *= k
        if not ok.all():  # above the horizon (no floor point): turn with the robot only
            yaw = math.atan2(rotation[1, 0], rotation[0, 0])
            self.particles[~ok, 0] -= cam.focal_px * math.tan(yaw)

    def predict(self, dt_s: float) -> None:
        """Step 2: equation 11 for the particles (noise from Q11) and the Kalman filter."""
        s = self.settings
        dt = max(float(dt_s), 1e-6)
        q = s.q_xy * self.scale**2
        n = len(self.particles)
        # one axis of Q11: [[dt^3/3, dt^2/2], [dt^2/2, dt]] q; its Cholesky factor
        chol = np.linalg.cholesky(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]) * q)
        noise = self.rng.standard_normal((n, 2, 2)) @ chol.T  # (n, axis, [pos, vel])
        p = self.particles
        p[:, 0] += p[:, 2] * dt + noise[:, 0, 0]
        p[:, 1] += p[:, 3] * dt + noise[:, 1, 0]
        p[:, 2] += noise[:, 0, 1]
        p[:, 3] += noise[:, 1, 1]
        kf = self.kf
        kf.F = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
        qw = s.q_wh * self.scale**2
        kf.Q = np.block(
            [
                [dt**3 / 3 * qw * np.eye(2), dt**2 / 2 * qw * np.eye(2)],
                [dt**2 / 2 * qw * np.eye(2), dt * qw * np.eye(2)],
            ]
        )
        kf.predict()
        kf.x[:2] = np.maximum(kf.x[:2], 1.0)

    def update(self, regions: np.ndarray) -> bool:
        """Steps 3-6 with the frame's regions (M, 4) [x, y, w, h]; False when no region has
        the target's size (then the particles keep their weights and the size its prediction)."""
        s = self.settings
        regions = np.asarray(regions, dtype=float).reshape(-1, 4)
        kf = self.kf
        # step 4, preprocessing: regions of a size like the predicted one (Mahalanobis)
        S = kf.H @ kf.P @ kf.H.T + kf.R
        d = regions[:, 2:] - kf.x[:2]
        m2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(S), d)
        kept = self.kept = regions[m2 <= s.shape_gate]
        self.measured = len(kept) > 0
        if not self.measured:
            return False
        # each particle's nearest kept region; the weight of equation 14
        diff = self.particles[:, None, :2] - kept[None, :, :2]  # (N, M, 2)
        dist2 = (diff**2).sum(axis=2)
        nearest = np.argmin(dist2, axis=1)
        sig2 = (s.sigma_xy_px * self.scale) ** 2
        logw = -0.5 * dist2[np.arange(len(nearest)), nearest] / sig2  # (14), up to a constant
        w = np.exp(logw - logw.max())
        self.weights = w / w.sum()
        self.map_index = int(np.argmax(self.weights))  # E(S) = S_MAP
        # step 5: the Kalman filter with the kept region nearest the MAP particle
        kf.update(kept[nearest[self.map_index], 2:])
        kf.x[:2] = np.maximum(kf.x[:2], 1.0)
        return True

    def step(
        self,
        regions: np.ndarray,
        dt_s: float,
        rotation: np.ndarray | None = None,
        translation: np.ndarray | None = None,
    ) -> bool:
        """Steps 1-6, with the robot's motion since the last frame when known."""
        self.resample()
        if rotation is not None:
            self.ego_motion(rotation, np.zeros(2) if translation is None else translation)
        self.predict(dt_s)
        return self.update(regions)
