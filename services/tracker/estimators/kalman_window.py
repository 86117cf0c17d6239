"""Seed 004 (Ristić-Durrant et al.): a Kalman filter per person, gated by an adaptive search window.

filterpy's :class:`~filterpy.kalman.KalmanFilter` on the shared state [x, y, vx, vy] (base
frame), constant velocity, the measurement is the candidate's position (seed 004 §5: "the
prediction states include the position and velocity of target human ...; measurement state is
position of target human"):

    predict   x' = F x,  P' = F P F^T + Q
              F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
              Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per axis   (Q_continuous_white_noise)
    update    z = [x, y],  H = [[1, 0, 0, 0], [0, 1, 0, 0]],  R = sigma_z^2 I

The search window (seed 004 §5, Fig. 9) is a square of side ``w`` centred on the Kalman
prediction, axis-aligned in the base frame, initially 1 m x 1 m. It looks for one person (the
seed's "complete set of 1 or 2 laser segments"; here a candidate is already one person):

    more than one candidate inside  ->  w shrinks by ``window_step_m`` while a smaller window
                                       still holds at least one ("decrease its size until only
                                       1 or 2 laser segments are detected")
    no candidate inside             ->  w grows by ``window_step_m`` until one is inside ("the
                                       window size increases until at least 1 laser segment
                                       is included")

within [``min_window_m``, ``max_window_m``]; the size carries over to the next scan. The window
is the gate: :meth:`KalmanWindowEstimator.distance` is the Chebyshev (L-inf) distance
max(|dx|, |dy|) to the prediction, adapts ``w`` to the scan's candidates, and
:meth:`~KalmanWindowEstimator.gate` is ``w / 2``. Seed 004 gives no step or bounds; they are
choices, marked below.

Vision's supervision (seed 004's 4 Hz "fusion tracking" correcting the 20 Hz laser tracker) is
the tracker's late vision (``core.Tracker``): verifications choose which track is the target;
the estimator itself sees laser candidates only. The seed has no deletion rule: a track is
given up (:meth:`~KalmanWindowEstimator.expired`) when its position spread
sqrt(var(x) + var(y)) exceeds half the largest window, i.e. the window could no longer be
expected to hold the person.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from .base import EstimatorBase

__all__ = ["KalmanWindowEstimator", "KalmanWindowSettings"]


class KalmanWindowSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # seed 004 §5: "A search window is initialized of size 1m x 1m"
    window_m: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """Side of the square search window when a track starts."""
    min_window_m: Annotated[float, msgspec.Meta(gt=0)] = 0.4  # not in seed 004
    max_window_m: Annotated[float, msgspec.Meta(gt=0)] = 2.0  # not in seed 004
    window_step_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1  # not in seed 004
    """How much the side changes per shrink or growth step (seed 004 Fig. 9: in steps)."""
    # seed 004 gives no noise values; the measurement is the mean of the leg points
    measurement_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """sigma_z of the measured x and y (the thesis's 100 mm range sigma)."""
    accel_noise: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """White-noise acceleration density q (m^2/s^3), as the UKF's."""
    initial_position_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """Standard deviation (m) of a new track's position, in x and in y: the first detection's
    accuracy."""
    initial_velocity_std_mps: Annotated[float, msgspec.Meta(gt=0)] = 0.7
    """Standard deviation (m/s) of a new track's velocity, in x and in y (it starts at 0):
    about a walking speed, since a new person's motion is unknown."""

    def __post_init__(self) -> None:
        if not self.min_window_m <= self.window_m <= self.max_window_m:
            raise ValueError(
                f"window_m: {self.window_m} must lie in [min_window_m, max_window_m] = "
                f"[{self.min_window_m}, {self.max_window_m}]"
            )


class KalmanWindowEstimator(EstimatorBase):
    """One person's Kalman filter and search window (seed 004). ``rng`` is unused."""

    name = "kalman_window"
    settings_type = KalmanWindowSettings

    def __init__(
        self,
        x_m: float,
        y_m: float,
        settings: KalmanWindowSettings | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        s = settings or KalmanWindowSettings()
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise ValueError(f"non-finite initial position ({x_m}, {y_m})")
        self.settings = s
        from filterpy.kalman import KalmanFilter  # here: filterpy + scipy.stats cost ~1 s

        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = np.array([x_m, y_m, 0.0, 0.0])
        pv, vv = s.initial_position_std_m**2, s.initial_velocity_std_mps**2
        kf.P = np.diag([pv, pv, vv, vv])
        kf.H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
        kf.R = np.eye(2) * s.measurement_std_m**2
        self._kf = kf
        self._dt = -1.0
        self.window_m = s.window_m
        """Current side of the search window (m); the gate is half of it."""

    @property
    def mean(self) -> np.ndarray:
        return self._kf.x.copy()

    @property
    def covariance(self) -> np.ndarray:
        return self._kf.P.copy()

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        """x <- [R p + t, R v], P <- B P B^T with B = diag(R, R); the window keeps its size."""
        kf = self._kf
        big = np.zeros((4, 4))
        big[:2, :2] = rotation
        big[2:, 2:] = rotation
        kf.x = big @ kf.x
        kf.x[:2] += translation
        kf.P = big @ kf.P @ big.T

    def predict(self, dt_s: float, misses: int = 0) -> None:
        dt = max(dt_s, 1e-3)
        if dt != self._dt:  # scans mostly come at one rate: F and Q are reused
            F = np.eye(4)
            F[0, 2] = F[1, 3] = dt  # x' = x + vx dt, y' = y + vy dt
            # Q per axis q [[dt^3/3, dt^2/2], [dt^2/2, dt]], state order [x, y, vx, vy]
            q = self.settings.accel_noise
            from filterpy.common import Q_continuous_white_noise

            Q = Q_continuous_white_noise(2, dt, q, block_size=2, order_by_dim=False)
            self._kf.F, self._kf.Q, self._dt = F, Q, dt
        self._kf.predict()

    def distance(self, points: np.ndarray, misses: int = 0) -> np.ndarray:
        """Chebyshev distance max(|dx|, |dy|) of each (n, 2) candidate to the prediction; adapts
        the window to this scan's candidates (module doc), so :meth:`gate` is its half side."""
        x = self._kf.x
        d = np.maximum(np.abs(points[:, 0] - x[0]), np.abs(points[:, 1] - x[1]))
        self._adapt(d)
        return d

    def _adapt(self, d: np.ndarray) -> None:
        s = self.settings
        w = self.window_m
        step = s.window_step_m
        eps = 1e-9
        inside = int(np.count_nonzero(d <= w / 2))
        if inside > 1:
            nearest = float(d.min())
            # shrink while the smaller window still holds one candidate and more than one is in
            while inside > 1 and w - step >= s.min_window_m - eps and (w - step) / 2 >= nearest:
                w -= step
                inside = int(np.count_nonzero(d <= w / 2))
        elif inside == 0:
            while inside == 0 and w + step <= s.max_window_m + eps:
                w += step
                inside = int(np.count_nonzero(d <= w / 2))
        self.window_m = min(max(w, s.min_window_m), s.max_window_m)

    def gate(self, misses: int = 0) -> float:
        return self.window_m / 2

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        R = None if noise_scale == 1.0 else self._kf.R * noise_scale**2
        self._kf.update(np.asarray(point, dtype=float)[:2], R=R)
        kf = self._kf
        kf.P = 0.5 * (kf.P + kf.P.T)

    def expired(self) -> bool:
        P = self._kf.P
        return math.sqrt(P[0, 0] + P[1, 1]) > self.settings.max_window_m / 2
