"""What every estimator offers: one person's state [x, y, vx, vy] in the current base frame.

An estimator is a small role object (Stone Soup's predictor + updater in one): the tracker
(``core.Tracker``) owns one per tracked person and calls, once per scan,

1. :meth:`Estimator.ego_motion` with the SE(2) change of the robot frame between the previous
   scan and this one (``p1 = R p0 + t``; velocities rotate with ``R``),
2. :meth:`Estimator.predict` with the time between the scans,
3. :meth:`Estimator.distance` to gate and associate the scan's candidates,
4. :meth:`Estimator.update` with the associated candidate's position, if any.

``mean`` (4,) and ``covariance`` (4, 4) are the estimate after the last call. ``gate`` is the
largest :meth:`distance` an association may have; ``expired`` says when the estimator itself
wants the track deleted (the UKF's variance rule); the tracker adds its miss-count rule.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from followbot.geometry import wrap_angle

__all__ = ["Estimator", "wrap_angle"]


@runtime_checkable
class Estimator(Protocol):
    name: str

    @property
    def mean(self) -> np.ndarray: ...

    @property
    def covariance(self) -> np.ndarray: ...

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None: ...

    def predict(self, dt_s: float, misses: int) -> None: ...

    def distance(self, points: np.ndarray, misses: int) -> np.ndarray:
        """(n,) association distance of each (n, 2) candidate; compared with :meth:`gate`."""
        ...

    def gate(self, misses: int) -> float: ...

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        """Correct with a measured position; ``noise_scale`` multiplies the measurement's
        standard deviations (the tracker's one_leg_noise_scale: a lone leg says less about
        where the person is than the middle of two)."""
        ...

    def expired(self) -> bool: ...
