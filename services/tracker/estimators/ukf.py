"""Seed 002 (Bellotto & Hu): an unscented Kalman filter per person, gated by Mahalanobis distance.

filterpy's :class:`~filterpy.kalman.UnscentedKalmanFilter` with Merwe scaled sigma points.
Seed 002 tracks [x, y, z, phi, v] with a heading-and-speed model; here the state is the shared
[x, y, vx, vy] with a constant-velocity model and white-noise acceleration, so every estimator
reports the same thing. What is kept from the seed (§III):

    measurement  z = [bearing, range] = [atan2(y, x), |p|]       (eq. 4)
    noise        sigma_b = pi/60 rad, sigma_r = 0.1 m             (eq. 18)
    residual     bearing differences wrapped to [-pi, pi)         (filterpy residual_z)
    gate         d = sqrt(nu^T S^-1 nu) <= lambda_L = 3.03        (eq. 24, P_G = 0.99)
    deletion     not updated for more than 2 s, or var(x) + var(y) > 2 m^2   (§III-C)

Process model (dt: time between scans, q: acceleration noise density):

    x' = F x,  F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    Q  = q * [[dt^3/3, dt^2/2], [dt^2/2, dt]] per axis
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from .base import EstimatorBase, wrap_angle

__all__ = ["UKFEstimator", "UKFSettings"]


class UKFSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # seed 002 eq. 18: sigma_b = pi/60 rad (3 deg), sigma_r = 0.1 m
    bearing_std_rad: Annotated[float, msgspec.Meta(gt=0)] = math.pi / 60
    range_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """Range measurement noise sigma_r (m; seed 002 eq. 18)."""
    accel_noise: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """White-noise acceleration density q (m^2/s^3)."""
    initial_position_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """Standard deviation (m) of a new track's position, in x and in y: the first detection's
    accuracy."""
    initial_velocity_std_mps: Annotated[float, msgspec.Meta(gt=0)] = 0.7
    """Standard deviation (m/s) of a new track's velocity, in x and in y (it starts at 0):
    about a walking speed, since a new person's motion is unknown."""
    # seed 002 §III-C: lambda_L = 3.03 for legs (chi^2, P_G = 0.99)
    gate_sigmas: Annotated[float, msgspec.Meta(gt=0)] = 3.03
    # seed 002 §III-C: deleted after 2 s without update or var(x) + var(y) > 2 m^2
    max_unseen_s: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    max_position_variance_m2: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """A track whose var(x) + var(y) exceeds this (m^2) is deleted (seed 002 III-C)."""


def _fx(x: np.ndarray, dt: float) -> np.ndarray:
    return np.array([x[0] + dt * x[2], x[1] + dt * x[3], x[2], x[3]])


def _hx(x: np.ndarray) -> np.ndarray:
    return np.array([math.atan2(x[1], x[0]), math.hypot(x[0], x[1])])


def _residual_z(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[0] = float(wrap_angle(d[0]))
    return d


def _z_mean(sigmas: np.ndarray, wm: np.ndarray) -> np.ndarray:
    """Weighted mean of [bearing, range] sigma points (bearing averaged on the circle)."""
    s = np.sum(np.sin(sigmas[:, 0]) * wm)
    c = np.sum(np.cos(sigmas[:, 0]) * wm)
    return np.array([math.atan2(s, c), float(np.sum(sigmas[:, 1] * wm))])


class UKFEstimator(EstimatorBase):
    """One person's UKF (seed 002). ``rng`` is unused (the filter is deterministic)."""

    name = "ukf"
    settings_type = UKFSettings

    def __init__(
        self,
        x_m: float,
        y_m: float,
        settings: UKFSettings | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        s = settings or UKFSettings()
        self.settings = s
        # alpha = 1, kappa = 0: non-negative mean weights, so P stays positive definite
        # imported here: filterpy pulls in scipy.stats (~1 s at every tracker start)
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

        points = MerweScaledSigmaPoints(4, alpha=1.0, beta=2.0, kappa=0.0)
        ukf = UnscentedKalmanFilter(
            dim_x=4,
            dim_z=2,
            dt=0.1,
            hx=_hx,
            fx=_fx,
            points=points,
            residual_z=_residual_z,
            z_mean_fn=_z_mean,
        )
        ukf.x = np.array([x_m, y_m, 0.0, 0.0])
        pv, vv = s.initial_position_std_m**2, s.initial_velocity_std_mps**2
        ukf.P = np.diag([pv, pv, vv, vv])
        ukf.R = np.diag([s.bearing_std_rad**2, s.range_std_m**2])
        self._ukf = ukf
        self._unseen_s = 0.0

    @property
    def mean(self) -> np.ndarray:
        return self._ukf.x.copy()

    @property
    def covariance(self) -> np.ndarray:
        return self._ukf.P.copy()

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        u = self._ukf
        big = np.zeros((4, 4))
        big[:2, :2] = rotation
        big[2:, 2:] = rotation
        u.x = big @ u.x
        u.x[:2] += translation
        u.P = big @ u.P @ big.T

    def predict(self, dt_s: float, misses: int = 0) -> None:
        dt = max(dt_s, 1e-3)
        q = self.settings.accel_noise
        block = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        qm = np.zeros((4, 4))
        qm[np.ix_([0, 2], [0, 2])] = block
        qm[np.ix_([1, 3], [1, 3])] = block
        self._ukf.Q = qm
        self._ukf.predict(dt=dt)
        self._symmetrise()
        self._unseen_s += dt_s

    def _symmetrise(self) -> None:
        u = self._ukf
        u.P = 0.5 * (u.P + u.P.T) + 1e-9 * np.eye(4)

    def distance(self, points: np.ndarray, misses: int = 0) -> np.ndarray:
        """Mahalanobis distance (eq. 24) of each candidate's [bearing, range] to the prediction."""
        u = self._ukf
        # innovation covariance S from the predicted sigma points (filterpy's own UT)
        sigmas_h = np.array([_hx(sp) for sp in u.sigmas_f])
        zp = _z_mean(sigmas_h, u.Wm)
        dz = sigmas_h - zp
        dz[:, 0] = wrap_angle(dz[:, 0])
        S = (dz.T * u.Wc) @ dz + u.R
        px, py = points[:, 0], points[:, 1]
        z = np.column_stack([np.arctan2(py, px), np.hypot(px, py)])
        nu = z - zp
        nu[:, 0] = wrap_angle(nu[:, 0])
        return np.sqrt(np.einsum("ni,ij,nj->n", nu, np.linalg.inv(S), nu))

    def gate(self, misses: int = 0) -> float:
        return self.settings.gate_sigmas

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        R = None if noise_scale == 1.0 else self._ukf.R * noise_scale**2
        self._ukf.update(_hx(np.asarray(point, dtype=float)), R=R)
        self._symmetrise()
        self._unseen_s = 0.0

    def expired(self) -> bool:
        s = self.settings
        P = self._ukf.P
        return self._unseen_s > s.max_unseen_s or P[0, 0] + P[1, 1] > s.max_position_variance_m2
