"""Leg detectors, chosen by name (issue 4): each turns a LaserScan into PersonCandidates.

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

import msgspec

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


def detector_settings(settings_cls: type, overrides: Mapping[str, Any]) -> Any:
    """``overrides`` as a ``settings_cls``; a key it lists as retired is a ValueError saying
    what to do instead, any other bad key or value msgspec's ValidationError."""
    retired = getattr(settings_cls, "retired_settings", None) or {}
    for key in overrides:
        if key in retired:
            raise ValueError(f"{key} {retired[key]}")
    return msgspec.convert(dict(overrides), settings_cls)


def make_detector(name: str = "thesis", settings: Any = None) -> LegDetector:
    """The detector called ``name`` with ``settings`` (Struct, mapping of overrides, or None)."""
    try:
        cls = REGISTRY.load(name)
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    settings_cls = cls.settings_type
    if isinstance(settings, Mapping):
        settings = detector_settings(settings_cls, settings)
    elif settings is not None and not isinstance(settings, settings_cls):
        raise TypeError(f"{name} expects {settings_cls.__name__}, got {type(settings).__name__}")
    return cls(settings)
