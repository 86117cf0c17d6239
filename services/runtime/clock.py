"""Judging message stamps: a stream's clock against the receiver's own.

A service believes the stamps it receives (every stage derives time from them), so one stamp
an hour ahead must not become the stream's "latest": every later, honest stamp would look
old. :class:`StampGuard` judges each stamp of one input stream against the stream's newest
accepted stamp *and* the local monotonic time that has passed since it arrived:

- ``ahead``: the stamp moved further ahead of the last accepted one than the receiver's clock
  did, by more than ``max_ahead_ns`` (a stamp in the future). Source and receiver clocks need
  not agree (simulated time starts near 0, a second machine's wall clock may be off): only how
  the stream's stamps advance against local time is judged.
- ``behind``: more than ``max_behind_ns`` older than the newest accepted stamp. Smaller
  reordering passes through; stages handle it (the tracker answers ``out_of_order``).

A rejected stamp is never adopted. But a source that really restarted (a bag looping, a
robot's computer rebooted, a simulator started again) sends stamps that are all "wrong" yet
consistent with each other: once ``restart_after`` rejected stamps in a row are consistent
among themselves (each one judged acceptable against the one before), the guard adopts the
new clock and answers ``restart``, so the stage can drop its state and start cleanly. A good
stamp in between clears that count, so a stranger's stray stamps interleaved with an honest
stream never take it over.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

__all__ = ["ClockSettings", "StampGuard", "Verdict"]

Verdict = Literal["ok", "ahead", "behind", "restart"]


class ClockSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """How a service judges the stamps of the messages it receives (docs/runtime.md, "Clocks")."""

    max_ahead_s: Annotated[float, msgspec.Meta(gt=0, le=86_400)] | None = 1.0
    """A stamp that moved this much further ahead of the stream's newest accepted stamp than
    local time did is rejected (null: no limit, for lock-step runs whose source sets its own
    pace)."""
    max_behind_s: Annotated[float, msgspec.Meta(gt=0, le=86_400)] | None = 1.0
    """A stamp this much older than the stream's newest accepted stamp is rejected (null: no
    limit). Smaller reordering reaches the stage."""
    restart_after: Annotated[int, msgspec.Meta(ge=2, le=1000)] = 3
    """This many rejected stamps in a row, consistent with each other, mean the source really
    restarted: its new clock is adopted and the stage starts afresh."""


class StampGuard:
    """Judges the stamps of one stream (see the module docstring)."""

    def __init__(
        self, max_ahead_ns: int | None, max_behind_ns: int | None, restart_after: int = 3
    ) -> None:
        if restart_after < 2:
            raise ValueError("restart_after must be >= 2")
        self.max_ahead_ns = max_ahead_ns
        self.max_behind_ns = max_behind_ns
        self.restart_after = restart_after
        self.newest_ns: int | None = None
        """The newest accepted stamp (None: nothing accepted yet)."""
        self._newest_local_ns = 0
        self._suspects: list[tuple[int, int]] = []  # rejected (stamp, local) in a row
        self.rejected = {"ahead": 0, "behind": 0}
        self.restarts = 0

    @classmethod
    def from_settings(cls, s: ClockSettings) -> StampGuard:
        def ns(v: float | None) -> int | None:
            return None if v is None else int(v * 1e9)

        return cls(ns(s.max_ahead_s), ns(s.max_behind_s), s.restart_after)

    def _fits(self, stamp: int, local: int, ref_stamp: int, ref_local: int) -> Verdict:
        ahead = (stamp - ref_stamp) - (local - ref_local)
        if self.max_ahead_ns is not None and ahead > self.max_ahead_ns:
            return "ahead"
        if self.max_behind_ns is not None and stamp < ref_stamp - self.max_behind_ns:
            return "behind"
        return "ok"

    def judge(self, stamp_ns: int, local_ns: int) -> Verdict:
        """The verdict on a message stamped ``stamp_ns`` that arrived at ``local_ns``
        (``time.monotonic_ns()``). ``ok`` and ``restart``: deliver it; else drop it."""
        if self.newest_ns is None:
            self._adopt(stamp_ns, local_ns)
            return "ok"
        verdict = self._fits(stamp_ns, local_ns, self.newest_ns, self._newest_local_ns)
        if verdict == "ok":
            self._suspects.clear()
            if stamp_ns > self.newest_ns:
                self._adopt(stamp_ns, local_ns)
            return "ok"
        if self._suspects and self._fits(stamp_ns, local_ns, *self._suspects[-1]) != "ok":
            self._suspects.clear()  # not one clock with the last suspect: start a new run
        self._suspects.append((stamp_ns, local_ns))
        if len(self._suspects) >= self.restart_after:
            self._suspects.clear()
            self._adopt(stamp_ns, local_ns)
            self.restarts += 1
            return "restart"
        self.rejected[verdict] += 1
        return verdict

    def _adopt(self, stamp_ns: int, local_ns: int) -> None:
        self.newest_ns = stamp_ns
        self._newest_local_ns = local_ns

    def reset(self) -> None:
        """Forget the stream (the next stamp is accepted as it comes)."""
        self.newest_ns = None
        self._suspects.clear()
