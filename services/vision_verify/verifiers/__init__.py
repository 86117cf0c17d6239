"""Verifier plugins (entry-point group ``followbot.verifiers``): histogram, face, meanshift.

Each is a class with ``name``, ``settings_type`` (a frozen msgspec Struct whose defaults are
the seed's values) and the :class:`~followbot.services.vision_verify.core.Verifier` methods.
"""

from __future__ import annotations

from typing import Any

from followbot.services.runtime.plugins import Registry, UnknownPlugin

__all__ = ["REGISTRY", "make_verifier"]

REGISTRY = Registry("verifiers")


def make_verifier(name: str, settings: Any = None):
    """The verifier ``name`` with ``settings`` (Struct, mapping of overrides, or None)."""
    try:
        cls = REGISTRY.load(name)
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    s = REGISTRY.settings(name, cls, settings)
    return cls() if s is None else cls(s)
