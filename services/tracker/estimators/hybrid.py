"""Seed 001's hybrid particle filter (Zhuang et al. 3.3, 4): a person in the image plane.

The state splits in two (equation 10): the position part S = [x, y, vx, vy] (pixels, px/s; the
centre of the target's rectangle) is a particle filter of ``particles`` samples (150, seed 5.1);
the shape part B = [w, h, dw, dh] (the rectangle's size and its rate of change) is a Kalman
filter (filterpy's KalmanFilter). Both move by the near-constant-velocity model of equation 11
with the white-acceleration noise of Q11 / Q22:

    Phi' = [[I2, dt I2], [O2, I2]]
    Q11  = [[dt^3/3 q, dt^2/2 q], [dt^2/2 q, dt q]],  q = diag(q_x, q_y)    (Q22: q_w = q_h)

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

from followbot.schemas import PersonCandidates
from followbot.services.runtime.ground_plane import GroundCamera

from .base import EstimatorBase
from .particle import systematic_resample

__all__ = ["HybridEstimator", "HybridFilter", "HybridSettings"]

_REF_WIDTH = 320.0  # pixel settings are given for a 320 px wide image


class HybridSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    particles: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 150  # seed 5.1: 150 particles
    q_x: Annotated[float, msgspec.Meta(gt=0)] = 4000.0
    """q_x of Q11: white acceleration spectral density along the image's rows, px^2/s^3 (at
    320 px wide)."""
    q_y: Annotated[float, msgspec.Meta(gt=0)] = 4000.0
    """q_y of Q11, up and down the image, px^2/s^3."""
    q_wh: Annotated[float, msgspec.Meta(gt=0)] = 1000.0
    """q_w = q_h of Q22, px^2/s^3."""
    sigma_xy_px: Annotated[float, msgspec.Meta(gt=0)] = 8.0
    """sigma_x = sigma_y of R in equation 14 (the weight's Gaussian), px."""
    sigma_wh_px: Annotated[float, msgspec.Meta(gt=0)] = 6.0
    """sigma_w = sigma_h of R for the Kalman filter's measurement, px."""
    shape_gate: Annotated[float, msgspec.Meta(gt=0)] = 13.8
    """Mahalanobis gate on a region's size (chi-square, 2 dof: 13.8 keeps 99.9 %)."""
    camera: GroundCamera = msgspec.field(default_factory=GroundCamera)
    """The camera the rectangles come from (equations 15-16): the same as camera_blobs'."""
    region_bottom_m: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    """How far above the floor the tracked region's bottom edge is (m); the same as
    camera_blobs' region_bottom_m. 0: the region reaches the floor (the seed)."""
    gate_px: Annotated[float, msgspec.Meta(gt=0)] = 40.0
    """As a tracker estimator: a candidate whose region's bottom centre lies at most this far
    (pixels at 320 px wide) from the estimate's may be associated with the track. In the image,
    as the filter works: on the floor the same pixel error is metres far away (the seed has
    one person and no gate)."""
    max_range_m: Annotated[float, msgspec.Meta(gt=0)] = 12.0
    """As a tracker estimator: a floor point farther than this (a rectangle's bottom near the
    horizon) is not believed; the last one stays (the simulator's camera sees 12 m)."""
    max_unseen_s: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """As a tracker estimator: the track is given up after this long without an update."""
    velocity_smoothing: Annotated[float, msgspec.Meta(ge=0, lt=1)] = 0.7
    """As a tracker estimator: the floor velocity it reports is the change of the floor point
    between updates, smoothed v <- a v + (1 - a) dp / dt (the seed has none: it has no floor
    velocity, only the particles' image velocity)."""

    def __post_init__(self) -> None:
        self.camera.above_floor(self.region_bottom_m)  # a ValueError unless below the camera


class HybridFilter:
    """Particles over [x, y, vx, vy] in pixels, a Kalman filter over [w, h, dw, dh]."""

    def __init__(
        self, region: np.ndarray, settings: HybridSettings | None, rng: np.random.Generator
    ) -> None:
        from filterpy.kalman import KalmanFilter

        s = self.settings = settings or HybridSettings()
        self.rng = rng
        self.scale = s.camera.width / _REF_WIDTH
        # a region's bottom edge stands on the plane region_bottom_m above the floor
        self.camera = s.camera.above_floor(s.region_bottom_m)
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
        fx, fy = self.camera.pixel_to_floor(x, y + self.size[1] / 2.0, pan_rad)
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
        cam = self.camera
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
        n = len(self.particles)
        # one axis of Q11: [[dt^3/3, dt^2/2], [dt^2/2, dt]] q; its Cholesky factor, per axis
        unit = np.linalg.cholesky(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
        noise = self.rng.standard_normal((n, 2, 2)) @ unit.T  # (n, axis, [pos, vel])
        noise *= np.sqrt(np.array([s.q_x, s.q_y]) * self.scale**2)[None, :, None]
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


class HybridEstimator(EstimatorBase):
    """The hybrid filter as the tracker's estimator ``hybrid`` (seed 001 in ``--preset zhuang``).

    The tracker's state is a floor point [x, y, vx, vy] in the base frame; this filter's is
    an image rectangle. Each track holds one :class:`HybridFilter`:

    - :meth:`observe` keeps the scan's image regions (the candidates' ``box_px``, from
      camera_blobs); a new track starts its filter on the region nearest where the tracker
      started it (until then its mean is that point);
    - :meth:`ego_motion` is the seed's prediction through the floor, :meth:`predict` equation
      11, :meth:`update` steps 3-6 with *all* the frame's regions, as the seed weighs them (the
      associated candidate says only that the track was seen); :meth:`prepare_all` resamples
      (step 1) between scans;
    - :meth:`distance` is measured in the image, between the bottom centres of a candidate's
      region and the estimate's, like everything the filter does;
    - :attr:`mean` is the point under the MAP rectangle's bottom edge (read on the plane
      ``region_bottom_m`` above the floor), its velocity the smoothed change of that point
      between updates; :attr:`covariance` the spread of the particles' points, and a nominal
      velocity variance.

    The filter assumes the camera does not pan (the seed's is fixed; the controller's
    ``rule: zhuang`` holds the pan at 0). Candidates without ``box_px`` (a laser's) leave the
    filter without a measurement: it coasts.
    """

    name = "hybrid"
    settings_type = HybridSettings

    def __init__(
        self,
        x_m: float,
        y_m: float,
        settings: HybridSettings | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise ValueError(f"non-finite initial position ({x_m}, {y_m})")
        s = self.settings = settings or HybridSettings()
        self.rng = rng or np.random.default_rng()
        self.filter: HybridFilter | None = None
        self._p = np.array([x_m, y_m], dtype=float)  # the last believable floor point
        self._p_updated = self._p.copy()  # at the last update, carried by ego-motion
        self._v = np.zeros(2)
        self._unseen_s = 0.0
        self._since_update_s = 0.0
        self._regions = np.zeros((0, 4))
        self._camera = s.camera.above_floor(s.region_bottom_m)

    # ------------------------------------------------------------------ state

    @property
    def mean(self) -> np.ndarray:
        return np.concatenate([self._p, self._v])

    @property
    def covariance(self) -> np.ndarray:
        cov = np.eye(4) * 0.25
        f = self.filter
        if f is not None:
            h = f.size[1]
            fx, fy = self._camera.pixel_to_floor(f.particles[:, 0], f.particles[:, 1] + h / 2)
            ok = np.isfinite(fx)
            if ok.sum() >= 3:
                cov[:2, :2] = np.cov(np.stack([fx[ok], fy[ok]])) + np.eye(2) * 1e-4
        return cov

    def _refresh(self) -> None:
        """The point under the MAP rectangle, when it is on the floor within range."""
        if self.filter is None:
            return
        p = self.filter.floor_point()
        cam = self._camera
        if np.isfinite(p).all() and math.hypot(p[0] - cam.mount_x_m, p[1]) <= (
            self.settings.max_range_m
        ):
            self._p = p

    def _bottom_px(self) -> np.ndarray:
        """(2,) the estimate's bottom centre in the image."""
        if self.filter is not None:
            x, y = self.filter.position[:2]
            return np.array([x, y + self.filter.size[1] / 2.0])
        u, v = self._camera.floor_to_pixel(self._p[0], self._p[1])
        return np.array([float(u), float(v)])

    # ------------------------------------------------------------------ the steps

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        self._p = rotation @ self._p + translation
        self._p_updated = rotation @ self._p_updated + translation
        self._v = rotation @ self._v
        if self.filter is not None:
            self.filter.ego_motion(rotation, translation)
            self._refresh()

    def predict(self, dt_s: float, misses: int = 0) -> None:
        self._unseen_s += dt_s
        self._since_update_s += dt_s
        if self.filter is not None:
            self.filter.predict(dt_s)
            self._refresh()

    def observe(self, candidates: PersonCandidates) -> None:
        seen = [c for c in candidates.candidates if c.box_px is not None]
        self._regions = np.array([c.box_px for c in seen], dtype=float).reshape(-1, 4)
        width, cam = candidates.image_width, self.settings.camera
        if width and width != self._camera.width:
            cam = cam.scaled(width, round(cam.height * width / cam.width))
            self._camera = cam.above_floor(self.settings.region_bottom_m)
        if self.filter is None and seen:
            d = self.distance(np.array([[c.x_m, c.y_m] for c in seen]))
            i = int(np.argmin(d))
            if d[i] <= self.gate():
                # the filter reads pixels on the regions' plane: this camera already does
                s = msgspec.structs.replace(self.settings, camera=self._camera, region_bottom_m=0.0)
                self.filter = HybridFilter(self._regions[i], s, self.rng)
                self._refresh()

    def distance(self, points: np.ndarray, misses: int = 0) -> np.ndarray:
        """Image distance (pixels at 320 px wide) between each (n, 2) candidate's bottom
        centre and the estimate's; inf for a point the camera cannot see."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        u, v = self._camera.floor_to_pixel(pts[:, 0], pts[:, 1])
        b = self._bottom_px()
        d = np.hypot(u - b[0], v - b[1]) * _REF_WIDTH / self._camera.width
        return np.where(np.isfinite(d), d, np.inf)

    def gate(self, misses: int = 0) -> float:
        return self.settings.gate_px

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        """Seen: steps 3-6 with every region of the frame (or, before the filter has a region
        to start from, the associated candidate's position)."""
        if self.filter is None or not self.filter.update(self._regions):
            self._p = np.asarray(point, dtype=float)[:2].copy()
        else:
            self._refresh()
        if self._since_update_s > 0:
            v = (self._p - self._p_updated) / self._since_update_s
            a = self.settings.velocity_smoothing
            self._v = a * self._v + (1.0 - a) * v
        self._p_updated = self._p.copy()
        self._unseen_s = self._since_update_s = 0.0

    def expired(self) -> bool:
        return self._unseen_s > self.settings.max_unseen_s

    @classmethod
    def prepare_all(cls, estimators) -> None:
        """Step 1 of the next scan, between scans: resample by the last weights."""
        for e in estimators:
            if e.filter is not None:
                e.filter.resample()
