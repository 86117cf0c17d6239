"""Leg detectors, chosen by name: each turns a LaserScan into PersonCandidates.

``make_detector("thesis")`` builds the default; an unknown name fails with the valid names.
Detectors are plugins of the entry-point group ``followbot.detectors`` (the built-in ones are
declared in pyproject.toml), so another package can add its own: a class with ``name``,
``settings_type`` (a frozen msgspec Struct) and ``detect(scan, prediction=None)``.
Settings are passed as a Struct or as a mapping of overrides; a settings type may list keys it
no longer has in a class attribute ``retired_settings`` (key -> what to do instead, see
services/runtime/settings.py ``removed``/``renamed``), and overrides naming one are refused
with that message.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from followbot.services.runtime.plugins import Registry, UnknownPlugin

from ..core import LegDetector
from .arc import ArcSettings, InscribedAngleArcDetector
from .bellotto import BellottoSettings, EdgePatternDetector
from .derivative import DerivativeSegmentDetector, DerivativeSettings
from .iav import IAVSettings, InscribedAngleVarianceDetector
from .learned import LearnedSettings, RandomTreesLegDetector
from .thesis import ClusterLegDetector, ThesisSettings

__all__ = [
    "DETECTORS",
    "ArcSettings",
    "BellottoSettings",
    "ClusterLegDetector",
    "DerivativeSegmentDetector",
    "DerivativeSettings",
    "EdgePatternDetector",
    "IAVSettings",
    "InscribedAngleArcDetector",
    "InscribedAngleVarianceDetector",
    "LearnedSettings",
    "RandomTreesLegDetector",
    "ThesisSettings",
    "detector_settings",
    "make_detector",
]

#: The built-in detectors: name -> (detector class, settings class).
DETECTORS: dict[str, tuple[type, type]] = {
    "thesis": (ClusterLegDetector, ThesisSettings),
    "arc": (InscribedAngleArcDetector, ArcSettings),
    "iav": (InscribedAngleVarianceDetector, IAVSettings),
    "derivative": (DerivativeSegmentDetector, DerivativeSettings),
    "bellotto": (EdgePatternDetector, BellottoSettings),
    "learned": (RandomTreesLegDetector, LearnedSettings),
}


#: Every installed detector, built-in or from other packages.
REGISTRY = Registry("detectors")


def detector_settings(name: str, overrides: Mapping[str, Any] | None) -> Any:
    """The settings of detector ``name`` with ``overrides`` (plugins.Registry.settings: a
    retired key is refused with what to do instead, a bad key or value with the reason)."""
    return REGISTRY.settings(name, REGISTRY.load(name), overrides)


def make_detector(name: str = "thesis", settings: Any = None) -> LegDetector:
    """The detector called ``name`` with ``settings`` (Struct, mapping of overrides, or None)."""
    try:
        cls = REGISTRY.load(name)
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    return cls(REGISTRY.settings(name, cls, settings))
