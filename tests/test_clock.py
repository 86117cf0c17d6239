"""StampGuard: stamps judged against the stream and the receiver's clock (unit tests)."""

from __future__ import annotations

from examples import scan
from hypothesis import given
from hypothesis import strategies as st

from followbot.schemas import Keys, encode
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.clock import ClockSettings, StampGuard
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import NodeSettings

S = 1_000_000_000
HOUR = 3600 * S


def guard(**kw) -> StampGuard:
    return StampGuard.from_settings(ClockSettings(**kw))


def feed(g: StampGuard, stamps: list[int], period: int = S // 20, start: int = 0):
    """Verdicts for ``stamps`` arriving one ``period`` of local time apart."""
    return [g.judge(s, start + k * period) for k, s in enumerate(stamps)]


def stream(n: int, start: int, period: int = S // 20) -> list[int]:
    return [start + k * period for k in range(n)]


def test_an_honest_stream_is_accepted_whatever_its_clock_says():
    # simulated time near 0, a wall clock, a machine whose clock is a day off: all the same
    for origin in (0, 1_700_000_000 * S, 1_700_000_000 * S - 24 * HOUR):
        g = guard()
        assert set(feed(g, stream(100, origin))) == {"ok"}


def test_one_stamp_an_hour_ahead_is_rejected_and_never_becomes_the_newest():
    g = guard()
    good = stream(40, 10 * S)
    stamps = [*good[:20], good[19] + HOUR, *good[20:]]
    verdicts = feed(g, stamps)
    assert verdicts[20] == "ahead"
    assert set(verdicts[:20] + verdicts[21:]) == {"ok"}
    assert g.newest_ns == good[-1] and g.rejected == {"ahead": 1, "behind": 0}


def test_the_largest_stamp_there_is_is_rejected_too():
    g = guard()
    stamps = [*stream(10, 0), 2**63 - 1, *stream(10, 10 * S // 20)]
    verdicts = feed(g, stamps)
    assert verdicts[10] == "ahead" and verdicts.count("ok") == 20


def test_a_bogus_first_stamp_is_undone_by_the_honest_stamps_that_follow():
    g = guard(restart_after=3)
    verdicts = feed(g, [2**63 - 1, *stream(10, 5 * S)])
    # the first stamp had nothing to be judged against; three honest ones in a row win
    assert verdicts[:4] == ["ok", "behind", "behind", "restart"]
    assert set(verdicts[4:]) == {"ok"} and g.newest_ns == 5 * S + 9 * S // 20


def test_a_source_that_restarts_from_zero_is_followed_after_three_stamps():
    g = guard(restart_after=3)
    verdicts = feed(g, [*stream(50, 100 * S), *stream(10, 0)])
    assert set(verdicts[:50]) == {"ok"}
    assert verdicts[50:53] == ["behind", "behind", "restart"]
    assert set(verdicts[53:]) == {"ok"} and g.restarts == 1


def test_a_strangers_future_stamps_between_honest_ones_never_take_the_stream_over():
    g = guard(restart_after=3)
    honest = stream(60, 0)
    stamps = []
    for k, s in enumerate(honest):
        stamps.append(s)
        if k % 2:
            stamps.append(HOUR + k * S // 20)  # consistent among themselves, one hour ahead
    verdicts = feed(g, stamps, period=S // 40)
    assert "restart" not in verdicts
    assert g.newest_ns == honest[-1] and g.rejected["ahead"] == 30


def test_small_reordering_passes_to_the_stage():
    g = guard()
    verdicts = feed(g, [0, 2 * S // 20, S // 20, 3 * S // 20])
    assert verdicts == ["ok"] * 4 and g.newest_ns == 3 * S // 20


def test_no_limit_ahead_lets_a_lockstep_source_jump():
    g = guard(max_ahead_s=None)
    assert feed(g, [0, 10 * S, 3600 * S], period=1000) == ["ok", "ok", "ok"]


@given(
    st.lists(st.integers(min_value=1, max_value=S // 5), min_size=1, max_size=60),
    st.integers(min_value=0, max_value=2**62),
)
def test_any_stream_that_keeps_pace_with_local_time_is_never_rejected(gaps, origin):
    g = guard()
    stamp, local = origin, 0
    assert g.judge(stamp, local) == "ok"
    for gap in gaps:
        stamp, local = stamp + gap, local + gap
        assert g.judge(stamp, local) == "ok"


def test_a_node_counts_stamp_rejections_and_says_so_in_its_health():
    net = FakeNetwork()
    node = Node("unit", NodeSettings(), net.bus("unit"))
    got: list[int] = []
    restarts: list[int] = []
    node.subscribe(
        "sensors/scan", lambda m: got.append(m.stamp_ns), on_restart=lambda: restarts.append(1)
    )
    key = Keys("robot").topic("sensors/scan")

    def put(stamp: int) -> None:
        net.put(key, encode(scan(n=10, stamp_ns=stamp)))
        node.spin_once()

    put(100 * S)
    put(100 * S + HOUR)
    put(101 * S)
    h = node.health()
    assert got == [100 * S, 101 * S] and h.rejected == {"sensors/scan": 1}
    assert h.status == "degraded" and "rejected 1 sensors/scan (stamp ahead)" in h.reasons
    for s in (5, 6, 7):  # the source started again from nothing
        put(s)
    assert got == [100 * S, 101 * S, 7] and restarts == [1]
