"""Per-person estimators, chosen by name (DESIGN.md "Presets").

``estimator_factory("particle")`` returns a callable ``(x_m, y_m, rng) -> Estimator`` that the
tracker calls for each new track. Estimators are plugins of the entry-point group
``followbot.estimators`` (the built-in ones are declared in pyproject.toml), so another package
can add its own: a class with ``name``, ``settings_type`` (a frozen msgspec Struct) and the
members of :class:`~.base.Estimator` (deriving from :class:`~.base.EstimatorBase` supplies the
batch steps and the optional parts), constructed as ``cls(x_m, y_m, settings, rng)``.
An unknown name fails with the list of valid ones.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from followbot.services.runtime.plugins import Registry

from .base import Estimator, EstimatorBase, check_estimator, wrap_angle
from .hybrid import HybridEstimator, HybridSettings
from .kalman_window import KalmanWindowEstimator, KalmanWindowSettings
from .nearest import NearestFeatureEstimator, NearestSettings
from .particle import (
    ParticleEstimator,
    ParticleSettings,
    sorted_copy_resample,
    systematic_resample,
)
from .ukf import UKFEstimator, UKFSettings

__all__ = [
    "BUILTIN",
    "Estimator",
    "EstimatorBase",
    "HybridEstimator",
    "HybridSettings",
    "KalmanWindowEstimator",
    "KalmanWindowSettings",
    "NearestFeatureEstimator",
    "NearestSettings",
    "ParticleEstimator",
    "ParticleSettings",
    "UKFEstimator",
    "UKFSettings",
    "check_estimator",
    "estimator_factory",
    "registry",
    "sorted_copy_resample",
    "systematic_resample",
    "wrap_angle",
]

#: The built-in estimators (also declared as entry points).
BUILTIN: dict[str, type] = {
    "particle": ParticleEstimator,
    "ukf": UKFEstimator,
    "kalman_window": KalmanWindowEstimator,
    "nearest": NearestFeatureEstimator,
    "hybrid": HybridEstimator,
}

registry = Registry("estimators")

EstimatorFactory = Callable[[float, float, np.random.Generator], Estimator]


def _load(name: str) -> type:
    if name in BUILTIN and name not in registry.names():
        return BUILTIN[name]  # running from a tree whose entry points are not installed yet
    return registry.load(name)


def estimator_factory(name: str = "particle", settings: Any = None) -> EstimatorFactory:
    """A constructor of ``name``'s estimators with ``settings`` (a Struct or a mapping)."""
    cls = _load(name)
    check_estimator(cls)
    s = registry.settings(name, cls, settings)

    def make(x_m: float, y_m: float, rng: np.random.Generator) -> Estimator:
        return cls(x_m, y_m, s, rng)

    make.estimator_name = name  # type: ignore[attr-defined]
    make.estimator_class = cls  # type: ignore[attr-defined]
    return make
