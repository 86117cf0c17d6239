"""monitor: watch topics like ``ros2 topic hz``: rates, losses, rejects and latency.

Subscribes to the topics in its settings, decodes and validates every message (so it also
shows malformed traffic), counts sequence-number gaps as losses, and measures each message's
age on arrival against the clock of its stream:

- a stream stamped with the wall clock (live sensors, the synthetic publisher): this host's
  clock at arrival minus ``stamp_ns``, the transport latency (meaningful on one host, or on
  hosts whose clocks are synchronised);
- a stream on a clock of its own (the simulator's starts near 0, a replay keeps old stamps:
  its first stamp is more than an hour from this host's clock): how much later than its
  stamp says a message came, the stream's clock aligned to this host's by its earliest
  message (the smallest arrival-minus-stamp seen). That shows delays and bursts; it cannot
  show a constant latency.

Logs a line per topic every ``report_period_s`` and, at exit, writes a JSON summary if
``summary`` names a file (``clock``: ``wall`` or ``stream``).

    followbot run monitor --set 'topics=[sensors/scan, sensors/odom]' --duration 10
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from pathlib import Path
from typing import Annotated

import msgspec

from followbot.schemas import Message, topic_type

from .node import Node
from .service import service_main
from .settings import NodeSettings
from .stats import Window

__all__ = ["MonitorSettings", "TopicStats", "main"]

#: A stream whose first stamp is this far from this host's clock has a clock of its own.
OWN_CLOCK_NS = 3600 * 1_000_000_000


class MonitorSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    topics: list[str] = msgspec.field(default_factory=lambda: ["sensors/scan"])
    """Topics to watch, under followbot/<robot>/ (docs/messages.md lists them)."""
    report_period_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """Seconds between two log lines per topic (and two rewrites of ``summary``)."""
    summary: str | None = None
    """Write a JSON summary here when stopping."""


class TopicStats:
    """Counters of one topic, fed with each good message."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.count = 0
        self.lost = 0
        self.restarts = 0
        self._last_seq: int | None = None
        self.age_ms = Window(100_000)
        self._period_age_ms = Window(1_000_000)
        self.first_ns = 0
        self.last_ns = 0
        self.clock: str | None = None
        """``wall`` or ``stream`` (see the module docstring), decided by the first message."""
        self._offset_ns: int | None = None
        self._t0 = time.monotonic_ns()
        #: One entry per report period: when, how many arrived, age p99 (bounded: ~11 days).
        self.series: deque[dict] = deque(maxlen=1_000_000)

    def add(self, message: Message, now_wall_ns: int) -> None:
        now = time.monotonic_ns()
        if self.count == 0:
            self.first_ns = now
        self.last_ns = now
        self.count += 1
        if self._last_seq is not None:
            gap = message.seq - self._last_seq - 1
            if gap > 0:
                self.lost += gap
            elif gap < 0:
                self.restarts += 1  # the publisher restarted its numbering
        self._last_seq = message.seq
        late_ns = now_wall_ns - message.stamp_ns
        if self.clock is None:
            self.clock = "wall" if abs(late_ns) < OWN_CLOCK_NS else "stream"
        if self.clock == "stream":
            if self._offset_ns is None or late_ns < self._offset_ns:
                self._offset_ns = late_ns
            late_ns -= self._offset_ns
        age = late_ns / 1e6
        self.age_ms.add(age)
        self._period_age_ms.add(age)

    def close_period(self) -> dict:
        """End a report period: append and return its figures."""
        (p99,) = self._period_age_ms.percentiles((99,))
        entry = {
            "t_s": round((time.monotonic_ns() - self._t0) / 1e9, 3),
            "received": len(self._period_age_ms),
            "age_p99_ms": None if math.isnan(p99) else p99,
        }
        self._period_age_ms = Window(1_000_000)
        self.series.append(entry)
        return entry

    def summary(self, rejected: int) -> dict:
        span = (self.last_ns - self.first_ns) / 1e9
        p50, p99 = self.age_ms.percentiles()
        return {
            "received": self.count,
            "clock": self.clock,
            "lost": self.lost,
            "rejected": rejected,
            "publisher_restarts": self.restarts,
            "rate_hz": (self.count - 1) / span if span > 0 else 0.0,
            "age_p50_ms": None if math.isnan(p50) else p50,
            "age_p99_ms": None if math.isnan(p99) else p99,
            "series": list(self.series),
        }


def setup(node: Node, settings: MonitorSettings) -> dict[str, TopicStats]:
    for t in settings.topics:
        topic_type(t)  # ValueError listing the valid topics
    stats = {t: TopicStats(t) for t in settings.topics}
    inputs = {}
    for t in settings.topics:
        s = stats[t]
        inputs[t] = node.subscribe(t, lambda m, s=s: s.add(m, time.time_ns()), policy="all")

    def report() -> None:
        for s in stats.values():
            s.close_period()
        for t, s in stats.items():
            d = s.summary(inputs[t].rejected)
            node.log.info(
                "%s: %d received, %.1f Hz, %d lost, %d rejected, age p50 %s ms p99 %s ms%s",
                t,
                d["received"],
                d["rate_hz"],
                d["lost"],
                d["rejected"],
                _fmt(d["age_p50_ms"]),
                _fmt(d["age_p99_ms"]),
                " (stream clock)" if d["clock"] == "stream" else "",
            )

    def write_summary() -> None:
        if settings.summary:
            out = {t: s.summary(inputs[t].rejected) for t, s in stats.items()}
            Path(settings.summary).write_text(json.dumps(out, indent=2) + "\n")

    node.every(settings.report_period_s, report, name="report")
    # Keep the summary file current, so a monitor that is killed still leaves figures.
    node.every(settings.report_period_s, write_summary, name="summary")
    node.on_stop(write_summary)
    return stats


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def main(argv: list[str] | None = None) -> int:
    return service_main("monitor", MonitorSettings, setup, argv, __doc__)
