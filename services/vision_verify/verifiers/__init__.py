"""Verifier plugins (entry-point group ``followbot.verifiers``): histogram, face, meanshift.

Each is a class with ``name``, ``settings_type`` (a frozen msgspec Struct whose defaults are
the seed's values) and the :class:`~followbot.services.vision_verify.core.Verifier` methods.
"""

from __future__ import annotations

from followbot.services.runtime.plugins import Registry

__all__ = ["REGISTRY", "make_verifier"]

REGISTRY = Registry("verifiers")


def make_verifier(name: str, settings: dict | None = None):
    """Instantiate the verifier ``name`` with settings given as a plain mapping (strict)."""
    import msgspec

    from followbot.services.runtime.plugins import UnknownPlugin

    try:
        cls = REGISTRY.load(name)
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    st = getattr(cls, "settings_type", None)
    if st is None:
        return cls()
    try:
        return cls(msgspec.convert(settings or {}, st, strict=False))
    except msgspec.ValidationError as exc:
        raise ValueError(f"verifier_settings for {name!r}: {exc}") from None
