"""The source's side of a lock-step run (docs/runtime.md, "Lock-step runs").

A :class:`LockstepBarrier` watches the stages' output topics; after publishing the scan with
stamp ``k``, the source calls :meth:`~LockstepBarrier.wait` ``(k)``, which returns once every
awaited topic has carried a message naming stamp ``k`` (or the timeout passes; the topics
still missing are returned and counted). Topics of stages that are not alive are not awaited.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict

from .node import Node

__all__ = ["LockstepBarrier"]

#: Output topic of each stage that answers every scan (rule 2 of the protocol).
STAGE_OUTPUT = {
    "laser_legs": "perception/candidates",
    "vision_verify": "perception/verification",
    "tracker": "tracking/target",
    "controller": "control/cmd_vel",
}


class LockstepBarrier:
    """Wait, per scan stamp, for each alive stage's answer."""

    def __init__(self, node: Node, stages: list[str], keep: int = 4096) -> None:
        unknown = set(stages) - set(STAGE_OUTPUT)
        if unknown:
            raise ValueError(f"no lock-step output known for {sorted(unknown)}")
        self.stages = list(stages)
        self._seen: dict[str, dict[int, None]] = defaultdict(dict)  # topic -> stamps (ordered)
        self._keep = keep
        self._alive: dict[str, bool] = {}
        self._cond = threading.Condition()
        self.timeouts: dict[str, int] = defaultdict(int)
        for stage in self.stages:
            topic = STAGE_OUTPUT[stage]
            node.subscribe(topic, lambda m, t=topic: self._saw(t, m.stamp_ns))
            node.watch_alive(stage, lambda up, s=stage: self._set_alive(s, up))
        self._node = node

    def _saw(self, topic: str, stamp_ns: int) -> None:
        with self._cond:
            seen = self._seen[topic]
            seen[stamp_ns] = None
            while len(seen) > self._keep:
                del seen[next(iter(seen))]
            self._cond.notify_all()

    def _set_alive(self, stage: str, up: bool) -> None:
        with self._cond:
            self._alive[stage] = up
            self._cond.notify_all()

    def alive(self) -> list[str]:
        self._node.spin_once()  # liveliness events are delivered through the node's loop
        return [s for s in self.stages if self._alive.get(s)]

    def wait_alive(self, timeout_s: float) -> list[str]:
        """Wait until every stage is alive; the ones that are not, after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if len(self.alive()) == len(self.stages):
                return []
            time.sleep(0.02)
        return [s for s in self.stages if s not in self.alive()]

    def wait(self, stamp_ns: int, timeout_s: float) -> list[str]:
        """Block until every alive stage answered ``stamp_ns``; the stages that did not."""
        deadline = time.monotonic() + timeout_s
        stages = self.alive()
        topics = {STAGE_OUTPUT[s]: s for s in stages}
        with self._cond:
            while True:
                missing = [t for t in topics if stamp_ns not in self._seen[t]]
                left = deadline - time.monotonic()
                if not missing or left <= 0:
                    break
                self._cond.wait(min(left, 0.05))
        for t in missing:
            self.timeouts[topics[t]] += 1
        return [topics[t] for t in missing]
