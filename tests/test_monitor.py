"""The monitor's ages: against the wall clock for live stamps, the stream's own clock else."""

from __future__ import annotations

from followbot.schemas import Health
from followbot.services.runtime.monitor import TopicStats

NS = 1_000_000_000
WALL_NS = 1_800_000_000 * NS  # a wall-clock time of this decade


def feed(stats: TopicStats, arrivals: list[tuple[int, int]]) -> None:
    """``(stamp_ns, arrival_ns)`` pairs."""
    for seq, (stamp, arrival) in enumerate(arrivals):
        stats.add(Health(stamp_ns=stamp, seq=seq, service="x"), arrival)


def test_a_simulated_clock_gets_ages_from_its_own_clock_not_decades():
    stats = TopicStats("sensors/scan")
    # sim stamps from 0 every 25 ms; arrivals 0.4 ms later, one 30 ms late
    arrivals = [(k * 25_000_000, WALL_NS + k * 25_000_000 + 400_000) for k in range(100)]
    stamp, arrival = arrivals[50]
    arrivals[50] = (stamp, arrival + 30_000_000)
    feed(stats, arrivals)
    s = stats.summary(0)
    assert s["clock"] == "stream"
    assert s["age_p50_ms"] == 0.0
    (p100,) = stats.age_ms.percentiles((100,))
    assert 29.9 < p100 < 30.1


def test_a_wall_clock_stream_shows_its_latency():
    stats = TopicStats("sensors/scan")
    feed(stats, [(WALL_NS + k * NS, WALL_NS + k * NS + 2_000_000) for k in range(10)])
    s = stats.summary(0)
    assert s["clock"] == "wall"
    assert abs(s["age_p50_ms"] - 2.0) < 1e-6
