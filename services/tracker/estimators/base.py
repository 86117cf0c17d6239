"""What every estimator offers: one person's state [x, y, vx, vy] in the current base frame.

An estimator is a small role object (Stone Soup's predictor + updater in one): the tracker
(``core.Tracker``) owns one per tracked person and calls, once per scan,

1. :meth:`Estimator.ego_motion` with the SE(2) change of the robot frame between the previous
   scan and this one (``p1 = R p0 + t``; velocities rotate with ``R``),
2. :meth:`Estimator.predict` with the time between the scans,
3. :meth:`Estimator.observe` with all of the scan's candidates (base frame): an estimator
   whose measurement weighs every candidate (seed 001's hybrid filter weighs each particle by
   its nearest image region) keeps them for its update; the others ignore them,
4. :meth:`Estimator.distance` to gate and associate the scan's candidates,
5. :meth:`Estimator.update` with the associated candidate's position, if any.

``mean`` (4,) and ``covariance`` (4, 4) are the estimate after the last call. ``gate`` is the
largest :meth:`distance` an association may have; ``expired`` says when the estimator itself
wants the track deleted (the UKF's variance rule); the tracker adds its miss-count rule.

With several tracks the tracker calls the class's batch steps instead of 1, 3 and 4 --
:meth:`Estimator.motion_all`, :meth:`Estimator.cost_all`, :meth:`Estimator.update_all` --
and, between scans, :meth:`Estimator.prepare_all`; each must give the numbers of the
per-track calls (up to floating-point rounding). :class:`EstimatorBase` implements them as
those per-track calls, and the rest of the protocol's optional parts as "not supported", so
an estimator that derives from it writes only the per-track methods. A class missing any
part of the protocol is refused when the tracker's settings load (:func:`check_estimator`).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from followbot.schemas import PersonCandidates
from followbot.services.common.geometry import wrap_angle

__all__ = ["Estimator", "EstimatorBase", "check_estimator", "wrap_angle"]


@runtime_checkable
class Estimator(Protocol):
    name: ClassVar[str]
    settings_type: ClassVar[type]
    """A frozen msgspec Struct; the class is constructed as ``cls(x_m, y_m, settings, rng)``."""

    @property
    def mean(self) -> np.ndarray: ...

    @property
    def covariance(self) -> np.ndarray: ...

    @property
    def coasts_in_place(self) -> bool:
        """A prediction without update leaves the estimate where it was (no velocity memory):
        the tracker then moves a track that missed on at its recent velocity."""
        ...

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None: ...

    def predict(self, dt_s: float, misses: int) -> None: ...

    def observe(self, candidates: PersonCandidates) -> None:
        """Every candidate of this scan, in the base frame, before association (step 3)."""
        ...

    def distance(self, points: np.ndarray, misses: int) -> np.ndarray:
        """(n,) association distance of each (n, 2) candidate; compared with :meth:`gate`."""
        ...

    def gate(self, misses: int) -> float: ...

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        """Correct with a measured position; ``noise_scale`` multiplies the measurement's
        standard deviations (the tracker's one_leg_noise_scale: a lone leg says less about
        where the person is than the middle of two)."""
        ...

    def mean_if(self, point: np.ndarray, noise_scale: float = 1.0) -> np.ndarray | None:
        """The mean :meth:`update` with ``point`` would give, without updating; None when the
        estimator cannot tell (the tracker then keeps no lone-leg shift for it)."""
        ...

    def expired(self) -> bool: ...

    def snapshot(self) -> Estimator:
        """An independent copy (the tracker's rollback goes back to it)."""
        ...

    @classmethod
    def motion_all(
        cls,
        estimators: Sequence[Any],
        rotation: np.ndarray | None,
        translation: np.ndarray | None,
        dt_s: float,
        misses: Sequence[int],
    ) -> None:
        """:meth:`ego_motion` (when ``rotation`` is given) then :meth:`predict`, for all."""
        ...

    @classmethod
    def cost_all(
        cls, estimators: Sequence[Any], points: np.ndarray, misses: Sequence[int]
    ) -> np.ndarray:
        """(T, n) :meth:`distance` of each point to each estimator; inf beyond its gate."""
        ...

    @classmethod
    def update_all(
        cls, estimators: Sequence[Any], points: np.ndarray, noise_scales: np.ndarray | None
    ) -> None:
        """:meth:`update` of estimator i with ``points[i]`` and ``noise_scales[i]`` (1)."""
        ...

    @classmethod
    def prepare_all(cls, estimators: Sequence[Any]) -> None:
        """Between scans, after the tracker's answer has left: work the next scan needs
        anyway (the particle filter's resampling and random draws)."""
        ...


#: Every member of :class:`Estimator` an estimator class must have.
PROTOCOL = (
    "name",
    "settings_type",
    "mean",
    "covariance",
    "coasts_in_place",
    "ego_motion",
    "predict",
    "observe",
    "distance",
    "gate",
    "update",
    "mean_if",
    "expired",
    "snapshot",
    "motion_all",
    "cost_all",
    "update_all",
    "prepare_all",
)


def check_estimator(cls: type) -> None:
    """Raise TypeError naming what ``cls`` lacks of the :class:`Estimator` protocol."""
    missing = [m for m in PROTOCOL if not hasattr(cls, m)]
    if missing:
        raise TypeError(
            f"estimator class {cls.__qualname__} lacks {', '.join(missing)} of the Estimator "
            "protocol (services/tracker/estimators/base.py; deriving from EstimatorBase "
            "supplies the batch steps and the optional parts)"
        )


class EstimatorBase:
    """The batch steps as per-track calls, and the optional parts as not supported."""

    coasts_in_place: bool = False

    def mean_if(self, point: np.ndarray, noise_scale: float = 1.0) -> np.ndarray | None:
        return None

    def observe(self, candidates: PersonCandidates) -> None:
        return None  # the associated candidate's position, given to update, is all it needs

    def snapshot(self) -> Any:
        return copy.deepcopy(self)

    @classmethod
    def motion_all(
        cls,
        estimators: Sequence[Any],
        rotation: np.ndarray | None,
        translation: np.ndarray | None,
        dt_s: float,
        misses: Sequence[int],
    ) -> None:
        for e, k in zip(estimators, misses, strict=True):
            if rotation is not None:
                e.ego_motion(rotation, translation)
            e.predict(dt_s, k)

    @classmethod
    def cost_all(
        cls, estimators: Sequence[Any], points: np.ndarray, misses: Sequence[int]
    ) -> np.ndarray:
        cost = np.empty((len(estimators), len(points)))
        for r, (e, k) in enumerate(zip(estimators, misses, strict=True)):
            d = e.distance(points, k)
            cost[r] = np.where(d <= e.gate(k), d, np.inf)
        return cost

    @classmethod
    def update_all(
        cls, estimators: Sequence[Any], points: np.ndarray, noise_scales: np.ndarray | None
    ) -> None:
        for i, (e, z) in enumerate(zip(estimators, points, strict=True)):
            e.update(z, 1.0 if noise_scales is None else float(noise_scales[i]))

    @classmethod
    def prepare_all(cls, estimators: Sequence[Any]) -> None:
        return None
