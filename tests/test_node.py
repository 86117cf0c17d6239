"""The node loop on the in-process fake bus: policies, rejection, errors, health, liveliness."""

from __future__ import annotations

import threading
import time

import pytest
from examples import scan

from followbot.schemas import Health, Keys, LaserScan, Odometry, TargetCommand, decode, encode
from followbot.services.runtime.bus import FakeNetwork, key_matches
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import NodeSettings

KEYS = Keys("robot")
SCAN_KEY = KEYS.topic("sensors/scan")


@pytest.fixture
def net():
    return FakeNetwork()


def make_node(net, service="unit", **kw) -> Node:
    return Node(service, NodeSettings(**kw), net.bus(service))


def test_all_policy_processes_every_message_in_order(net):
    node = make_node(net)
    got = []
    node.subscribe("sensors/scan", lambda m: got.append(m.seq), policy="all")
    for i in range(50):
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    node.spin_once()
    assert got == list(range(50))


def test_latest_policy_keeps_only_the_newest_unprocessed(net):
    node = make_node(net)
    got = []
    inp = node.subscribe("sensors/scan", lambda m: got.append(m.seq), policy="latest")
    for i in range(5):
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    node.spin_once()
    assert got == [4]
    assert inp.superseded == 4 and inp.dropped == 0


def test_bounded_queue_drops_oldest_and_counts(net):
    node = make_node(net)
    got = []
    inp = node.subscribe("sensors/scan", lambda m: got.append(m.seq), capacity=3, dispatch="loop")
    for i in range(10):
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    node.spin_once()
    assert got == [7, 8, 9]
    assert inp.dropped == 7
    h = node.health()
    assert h.dropped == {"sensors/scan": 7}
    assert h.status == "degraded" and "dropped 7 sensors/scan (input queue full)" in h.reasons
    # health judges the last period: with nothing dropped since, the node is well again
    later = node.health()
    assert later.dropped == {"sensors/scan": 7} and later.status == "ok" and later.reasons == []


def test_bad_payloads_are_counted_and_good_ones_still_processed(net, caplog):
    node = make_node(net)
    got = []
    inp = node.subscribe("sensors/scan", lambda m: got.append(m.seq))
    bad = [b"", b"\xc1", b"garbage", encode(Odometry(stamp_ns=1, x_m=0, y_m=0, yaw_rad=0))]
    for i, payload in enumerate(bad):
        net.put(SCAN_KEY, payload)
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    node.spin_once()
    assert got == [0, 1, 2, 3]
    assert inp.rejected == 4
    assert node.health().rejected == {"sensors/scan": 4}
    # rate-limited: one warning for the burst, not one per payload
    warnings = [r for r in caplog.records if "rejected sensors/scan" in r.getMessage()]
    assert len(warnings) == 1


def test_handler_exceptions_are_counted_and_the_loop_goes_on(net):
    node = make_node(net)
    got = []

    def handler(m: LaserScan) -> None:
        if m.seq % 2:
            raise RuntimeError("odd scan")
        got.append(m.seq)

    node.subscribe("sensors/scan", handler)
    for i in range(6):
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    node.spin_once()
    assert got == [0, 2, 4]
    h = node.health()
    assert h.errors == 3 and "odd scan" in h.last_error and h.status == "degraded"


def test_publisher_numbers_messages_and_checks_their_type(net):
    node = make_node(net)
    pub = node.publisher("sensors/scan")
    pub.put(scan(n=10))
    pub.put(scan(n=10))
    payloads = [p for k, p in net.published if k == SCAN_KEY]
    assert [decode(LaserScan, p).seq for p in payloads] == [0, 1]
    with pytest.raises(TypeError, match="carries LaserScan"):
        pub.put(TargetCommand(stamp_ns=1, action="acquire"))


def test_health_is_published_periodically_with_rates(net):
    node = make_node(net, health_period_s=0.05)
    healths = []
    net.bus("watcher").subscribe(KEYS.health("unit"), lambda p: healths.append(decode(Health, p)))
    node.subscribe("sensors/scan", lambda m: None)
    stop = threading.Timer(0.3, node.stop)
    stop.start()
    for i in range(20):
        net.put(SCAN_KEY, encode(scan(n=10, seq=i)))
    assert node.run() == 0
    assert len(healths) >= 3
    last = healths[-1]
    assert last.service == "unit" and last.received == {"sensors/scan": 20}
    assert last.status == "ok" and last.uptime_s > 0
    assert "in:sensors/scan" in healths[1].rates_hz


def test_liveliness_token_and_watch(net):
    events = []
    watcher = make_node(net, service="watcher")
    watcher.watch_alive("worker", events.append)
    worker = make_node(net, service="worker")
    watcher.spin_once()
    assert events == []  # not alive until it has set up and announces itself
    worker.announce()
    watcher.spin_once()
    worker.close()
    watcher.spin_once()
    assert events == [True, False]


def test_serve_last_answers_queries(net):
    owner = make_node(net, service="owner")
    asker = make_node(net, service="asker")
    assert asker.query("sensors/odom") == []
    pub = owner.publisher("sensors/odom", serve_last=True)
    pub.put(Odometry(stamp_ns=5, x_m=1, y_m=2, yaw_rad=0))
    (answer,) = asker.query("sensors/odom")
    assert answer.x_m == 1 and answer.stamp_ns == 5


def test_timers_fire_on_schedule_and_run_duration_ends(net):
    node = make_node(net)
    ticks = []
    node.every(0.02, lambda: ticks.append(time.monotonic()))
    t0 = time.monotonic()
    assert node.run(duration_s=0.25) == 0
    assert 0.24 <= time.monotonic() - t0 < 1.0
    assert 8 <= len(ticks) <= 13


def test_on_stop_runs_once_after_the_loop(net):
    node = make_node(net)
    calls = []
    node.on_stop(lambda: calls.append(1))
    node.every(0.01, node.stop)
    node.run()
    assert calls == [1]


@pytest.mark.parametrize(
    ("expr", "key", "match"),
    [
        ("a/b", "a/b", True),
        ("a/*", "a/b", True),
        ("a/*", "a/b/c", False),
        ("a/**", "a/b/c", True),
        ("a/**", "a", True),
        ("**/c", "a/b/c", True),
        ("a/*/c", "a/b/d", False),
    ],
)
def test_fake_key_matching_follows_zenoh(expr, key, match):
    assert key_matches(expr, key) is match


def test_lockstep_barrier_sees_an_answer_that_came_while_the_node_was_busy(net):
    """Nobody runs the source's node loop while it waits: an answer queued for that loop
    (because another handler held the node) must still end the wait, not its timeout."""
    from followbot.schemas import TrackState
    from followbot.services.runtime.lockstep import LockstepBarrier

    source = make_node(net, "source")
    barrier = LockstepBarrier(source, ["tracker"])
    tracker = make_node(net, "tracker")
    tracker.announce()
    assert barrier.wait_alive(5.0) == []
    answer = encode(TrackState(stamp_ns=7, status="initialising"))

    def answer_while_busy() -> None:
        time.sleep(0.2)  # while the source waits
        with source._lock:  # a handler of the source is running
            net.put(KEYS.topic("tracking/target"), answer)  # so this one is queued

    t = threading.Thread(target=answer_while_busy)
    t.start()
    missing = barrier.wait(7, timeout_s=30.0)
    t.join()
    assert missing == [] and barrier.timeouts == {}


def test_run_timer_runs_a_named_timer_now_and_keeps_its_schedule(net):
    node = Node("svc", NodeSettings(), net.bus("svc"))
    calls = []
    node.every(3600.0, lambda: calls.append(1), name="hourly")
    node.spin_once()
    assert calls == []  # not due for an hour
    node.run_timer("hourly")
    assert calls == [1]
    node.spin_once()
    assert calls == [1]  # its schedule did not move
    with pytest.raises(KeyError, match="no timer named 'daily'"):
        node.run_timer("daily")
