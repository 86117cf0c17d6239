"""Registries of swappable implementations, found through Python entry points.

A role (``services``, ``detectors``, ``verifiers``, ``estimators``...) is an entry-point group
``followbot.<role>``; each entry point names one implementation. Third-party packages add their
own by declaring entry points in that group; tests may :meth:`Registry.register` in-process.
An unknown name fails with the list of valid ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib.metadata import entry_points
from typing import Any

import msgspec

__all__ = ["PluginSettingsError", "Registry", "UnknownPlugin"]


class UnknownPlugin(LookupError):
    """No implementation of that name; the message lists the valid ones."""

    def __str__(self) -> str:  # LookupError would repr() the message
        return str(self.args[0])


class PluginSettingsError(ValueError):
    """Settings a plugin cannot take; the message names the role, the plugin and the key."""


class Registry:
    """Named implementations of one role."""

    def __init__(self, role: str) -> None:
        self.role = role
        self.group = f"followbot.{role}"
        self._local: dict[str, Any] = {}

    def _entry_points(self) -> dict[str, Any]:
        return {ep.name: ep for ep in entry_points(group=self.group)}

    def names(self) -> list[str]:
        return sorted(set(self._entry_points()) | set(self._local))

    def register(self, name: str, obj: Any) -> None:
        """Add an implementation in-process (it shadows an entry point of the same name)."""
        self._local[name] = obj

    def load(self, name: str) -> Any:
        if name in self._local:
            return self._local[name]
        ep = self._entry_points().get(name)
        if ep is None:
            valid = ", ".join(self.names()) or "(none installed)"
            raise UnknownPlugin(
                f"unknown {self.role[:-1] if self.role.endswith('s') else self.role} "
                f"{name!r}; valid names: {valid}"
            )
        return ep.load()

    def settings(self, name: str, cls: Any, settings: Any = None) -> Any:
        """``settings`` for the plugin ``name`` (class ``cls``) as its ``settings_type``: None
        gives the defaults, an instance is used as is, a mapping holds overrides of the
        defaults. A key the settings type lists in ``retired_settings`` is refused with what
        to do instead; a bad key or value with msgspec's reason. Every role builds its
        plugins' settings here, so every role validates them alike."""
        settings_type = getattr(cls, "settings_type", None)
        what = f"{self.role[:-1] if self.role.endswith('s') else self.role} {name!r}"
        if settings_type is None:
            if settings:
                raise PluginSettingsError(f"{what}: this {self.role[:-1]} takes no settings")
            return None
        if settings is None:
            return settings_type()
        if isinstance(settings, settings_type):
            return settings
        if not isinstance(settings, Mapping):
            raise TypeError(f"{what}: settings must be {settings_type.__name__} or a mapping")
        retired = getattr(settings_type, "retired_settings", None) or {}
        for key in settings:
            if key in retired:
                raise PluginSettingsError(f"{what}: {key} {retired[key]}")
        try:
            return msgspec.convert(dict(settings), settings_type, strict=False)
        except msgspec.ValidationError as exc:
            raise PluginSettingsError(f"{what}: {exc}") from None
