"""Registries of swappable implementations, found through Python entry points.

A role (``services``, ``detectors``, ``verifiers``, ``estimators``...) is an entry-point group
``followbot.<role>``; each entry point names one implementation. Third-party packages add their
own by declaring entry points in that group; tests may :meth:`Registry.register` in-process.
An unknown name fails with the list of valid ones.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any

__all__ = ["Registry", "UnknownPlugin"]


class UnknownPlugin(LookupError):
    """No implementation of that name; the message lists the valid ones."""

    def __str__(self) -> str:  # LookupError would repr() the message
        return str(self.args[0])


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
