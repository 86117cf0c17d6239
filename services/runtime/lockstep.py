"""Both sides of a lock-step run (docs/runtime.md, "Lock-step runs").

The source's side: a :class:`LockstepBarrier` watches the stages' output topics; after
publishing the scan with stamp ``k``, the source calls :meth:`~LockstepBarrier.wait` ``(k)``,
which returns once every awaited topic has carried a message naming stamp ``k`` (or the
timeout passes; the topics still missing are returned and counted). Topics of stages that are
not alive are not awaited.

A stage's side: :class:`HeldInputs` holds a message until what it must be combined with has
arrived (rule 5), because messages on different topics reach a stage in no guaranteed order.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable
from typing import Generic, TypeVar

from .node import Node

__all__ = ["HeldInputs", "LockstepBarrier"]

M = TypeVar("M")

#: Output topic of each stage that answers every scan (rule 2 of the protocol).
STAGE_OUTPUT = {
    "laser_odometry": "sensors/odom",  # a recording without odometry: odometry from its scans
    "laser_legs": "perception/candidates",
    "camera_blobs": "perception/candidates",  # seed 001's camera candidates (answer_on: scan)
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
        while True:
            # An answer that came while the node was busy with another handler waits in the
            # node's queue (nobody runs the node's loop here): serve it, or it would only be
            # seen after the timeout.
            self._node.spin_once()
            with self._cond:
                missing = [t for t in topics if stamp_ns not in self._seen[t]]
                left = deadline - time.monotonic()
                if not missing or left <= 0:
                    break
                self._cond.wait(min(left, 0.005))
        for t in missing:
            self.timeouts[topics[t]] += 1
        return [topics[t] for t in missing]


class HeldInputs(Generic[M]):
    """A stage's side of lock-step: ``process`` each offered message, in order, once
    ``ready(message)`` holds, or once it has waited ``wait_s`` (wall clock; counted in
    :attr:`timeouts`).

    Messages on different topics reach a stage in no guaranteed order: Zenoh delivers each
    subscription on its own thread, and one topic may come straight from the source while
    another comes through a stage (the tracker's odometry from the sim, its candidates through
    laser_legs). So "scan k" can be handled before the odometry of scan k, although the source
    sent that first. A stage whose output depends on such a pairing offers the message here and
    calls :meth:`release` whenever an input that ``ready`` looks at arrives. ``wait_s`` only
    bounds how long a stage waits for something that will not come (a source without
    odometry, a stage that died); a run whose waits time out is not deterministic.
    """

    def __init__(
        self,
        node: Node,
        process: Callable[[M], None],
        ready: Callable[[M], bool],
        wait_s: float,
        name: str,
    ) -> None:
        self._process, self._ready, self.wait_s = process, ready, wait_s
        self._held: deque[tuple[M, float]] = deque()
        self.waits = 0
        """Messages that could not be processed at once."""
        self.timeouts = 0
        """Messages processed after ``wait_s`` without what they waited for."""
        if wait_s > 0:  # nothing is ever held without a wait
            node.every(0.005, self._check, name=f"held_{name}")

    def clear(self) -> None:
        """Forget the held messages (the source restarted: they belong to its old clock)."""
        self._held.clear()

    def offer(self, message: M) -> None:
        if self._held or not self._ready(message):
            self._held.append((message, time.monotonic()))
            self.waits += 1
            return
        self._process(message)

    def release(self, force: bool = False) -> None:
        """Process the held messages that are ready now (``force``: the first one anyway)."""
        while self._held and (force or self._ready(self._held[0][0])):
            force = False
            self._process(self._held.popleft()[0])

    def _check(self) -> None:
        if self._held and time.monotonic() - self._held[0][1] > self.wait_s:
            self.timeouts += 1
            self.release(force=True)
