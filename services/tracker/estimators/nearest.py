"""Seed 003 (Livingston) §VII: the person is where the nearest feature is, within reach.

No filter: each scan the person's position becomes the nearest laser feature, if it lies
within the distance the person could have moved since the last update (seed 003 §VII steps
7-10):

    gate      g = v_max * tau + D          (tau: time since the last update, v_max: the
                                            "max person speed", D: the "maximum person diameter")
    distance  |z - p|                      (Euclidean, to the previous position p)
    update    p <- z                       (step 8: "update the target person position to be
                                            that of the nearest feature")

The seed keeps only a position. The shared state also has a velocity, here the finite
difference of successive positions, (z - p) / tau, clipped to v_max and smoothed
exponentially (``velocity_smoothing``; not in seed 003). ``motion_model: hold`` (default) keeps
p between updates as the seed does; ``constant_velocity`` moves it along that velocity.

``covariance`` is nominal (the seed has none): position variance per axis
sigma_p^2 + (v_max tau)^2 / 4 (the spread of a disc of the reachable radius), velocity variance
(v_max / 3)^2.

What of the seed's chain is here and what is not (the estimator sees positions only):

* steps 7-10, nearest "leg", else nearest "leg pair", within the gate: the gate and the
  nearest-position update are here. The preference of single legs over leg pairs is not: the
  tracker (``core.Tracker``) assigns candidates to tracks by least total distance whatever the
  candidate's ``pattern`` (the ``iav`` detector marks legs ``circle`` and pairs ``segment``).
* step 11, the vision bearing at the previous radius when no feature is in reach: not done.
  A verification in this system chooses a laser candidate of a past scan (late vision), it
  carries no bearing of its own; a track without a feature coasts (``hold``) instead.
* step 12, "declare the person position to be unknown" at the first scan without a feature:
  :meth:`NearestFeatureEstimator.expired` after ``max_unseen_s``; 0 gives the seed's rule, the
  default 1 s matches the tracker's own ``max_misses`` (thesis: ~1 s).
* re-location of a lost target by vision: the tracker's late vision (a verification chooses
  the candidate, whose track becomes the target) does this, by appearance rather than by the
  seed's "least angle mismatch".
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec
import numpy as np

from .base import EstimatorBase

__all__ = ["NearestFeatureEstimator", "NearestSettings"]


class NearestSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # seed 003 §VII step 8 names "max person speed" and "maximum person diameter", no values
    max_speed_mps: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """v_max: a brisk walk (not in seed 003)."""
    person_diameter_m: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """D: a person's shoulder width (not in seed 003)."""
    motion_model: Literal["hold", "constant_velocity"] = "hold"
    """hold: the position stays where the last feature was (seed 003); constant_velocity: it
    moves along the estimated velocity between updates (not in seed 003)."""
    velocity_smoothing: Annotated[float, msgspec.Meta(ge=0, lt=1)] = 0.5
    """v <- a v + (1 - a) (z - p) / tau; 0 keeps the raw difference (not in seed 003)."""
    # seed 003 §VII step 12: unknown at the first scan without a feature (max_unseen_s: 0)
    max_unseen_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """The estimator gives the track up after this long without a feature."""
    position_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """sigma_p of the reported covariance right after an update (nominal)."""


class NearestFeatureEstimator(EstimatorBase):
    """One person at the nearest feature in reach (seed 003). ``rng`` is unused."""

    name = "nearest"
    settings_type = NearestSettings

    def __init__(
        self,
        x_m: float,
        y_m: float,
        settings: NearestSettings | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        s = settings or NearestSettings()
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise ValueError(f"non-finite initial position ({x_m}, {y_m})")
        self.settings = s
        self._z = np.array([x_m, y_m], dtype=float)  # the last feature, in the current frame
        self._v = np.zeros(2)
        self._has_velocity = False
        self._unseen_s = 0.0

    @property
    def _p(self) -> np.ndarray:
        if self.settings.motion_model == "constant_velocity":
            return self._z + self._v * self._unseen_s
        return self._z

    @property
    def mean(self) -> np.ndarray:
        return np.concatenate([self._p, self._v])

    @property
    def covariance(self) -> np.ndarray:
        s = self.settings
        pv = s.position_std_m**2 + (s.max_speed_mps * self._unseen_s) ** 2 / 4
        vv = (s.max_speed_mps / 3) ** 2
        return np.diag([pv, pv, vv, vv])

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        """p <- R p + t, v <- R v."""
        self._z = rotation @ self._z + translation
        self._v = rotation @ self._v

    def predict(self, dt_s: float, misses: int = 0) -> None:
        self._unseen_s += dt_s  # constant_velocity: p = z + v tau (see _p)

    def distance(self, points: np.ndarray, misses: int = 0) -> np.ndarray:
        """Euclidean distance of each (n, 2) candidate to the current position."""
        p = self._p
        return np.hypot(points[:, 0] - p[0], points[:, 1] - p[1])

    def gate(self, misses: int = 0) -> float:
        s = self.settings
        return s.max_speed_mps * self._unseen_s + s.person_diameter_m  # seed 003 §VII step 8

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        """The position becomes the feature's; the velocity their difference over the time.
        (No noise model: ``noise_scale`` changes nothing.)"""
        s = self.settings
        z = np.asarray(point, dtype=float)[:2]
        if self._unseen_s > 0:
            v = (z - self._z) / self._unseen_s
            speed = float(np.hypot(*v))
            if speed > s.max_speed_mps:
                v *= s.max_speed_mps / speed  # a jump between legs is not a speed
            a = s.velocity_smoothing if self._has_velocity else 0.0
            self._v = a * self._v + (1.0 - a) * v
            self._has_velocity = True
        self._z = z.copy()
        self._unseen_s = 0.0

    def expired(self) -> bool:
        return self._unseen_s > self.settings.max_unseen_s
