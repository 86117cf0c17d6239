"""Real processes, real Zenoh sessions on loopback: exchange, bad input, clean shutdown."""

from __future__ import annotations

import json
import queue
import signal
import time

import pytest
from conftest import LivelinessWatch
from examples import scan

from followbot.schemas import Health, Keys, decode, encode

pytestmark = pytest.mark.multiprocess


def test_two_processes_exchange_scans(spawn, endpoint, robot, tmp_path, zenoh_session):
    summary = tmp_path / "monitor.json"
    keys = Keys(robot)
    sub = LivelinessWatch(zenoh_session, keys.alive("monitor"))
    monitor = spawn(
        "run",
        "monitor",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "topics=[sensors/scan, sensors/odom]",
        "--set",
        f"summary={summary}",
        "--set",
        "report_period_s=0.2",
    )
    sub.expect("PUT", timeout=10)
    synthetic = spawn(
        "run",
        "synthetic",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "scan_rate_hz=200",
        "--set",
        "count=100",
        "--set",
        "wait_for_subscribers_s=10",
    )
    assert synthetic.wait(30) == 0, synthetic.output
    time.sleep(0.5)
    monitor.signal(signal.SIGTERM)
    assert monitor.wait(5) == 0, monitor.output
    stats = json.loads(summary.read_text())["sensors/scan"]
    assert stats["received"] == 100, monitor.output
    assert stats["lost"] == 0 and stats["rejected"] == 0
    assert 100 < stats["rate_hz"] < 300
    assert stats["age_p50_ms"] is not None and stats["age_p50_ms"] < 100
    sub.undeclare()


def test_a_running_node_rejects_bad_payloads_and_keeps_good_ones(
    spawn, endpoint, robot, zenoh_session
):
    keys = Keys(robot)
    healths: queue.SimpleQueue = queue.SimpleQueue()
    hsub = zenoh_session.declare_subscriber(
        keys.health("monitor"), lambda s: healths.put(decode(Health, s.payload.to_bytes()))
    )
    sub = LivelinessWatch(zenoh_session, keys.alive("monitor"))
    monitor = spawn(
        "run",
        "monitor",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "health_period_s=0.2",
    )
    sub.expect("PUT", timeout=10)
    pub = zenoh_session.declare_publisher(keys.topic("sensors/scan"))
    deadline = time.monotonic() + 10
    while not pub.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.02)
    bad = [b"", b"\x00\x01", b"\xc1" * 100, encode(scan(n=8))[:-3], b"{json: no}"]
    for i, payload in enumerate(bad):
        pub.put(payload)
        pub.put(encode(scan(n=32, seq=i)))
    deadline = time.monotonic() + 10
    last = None
    while time.monotonic() < deadline:
        last = healths.get(timeout=5)
        if last.received.get("sensors/scan") == 10:
            break
    assert last is not None
    assert last.received == {"sensors/scan": 10}
    assert last.rejected == {"sensors/scan": len(bad)}
    assert last.errors == 0
    assert monitor.p.poll() is None, "the node died on bad input"
    monitor.signal(signal.SIGTERM)
    assert monitor.wait(5) == 0
    assert "rejected sensors/scan payload" in monitor.output
    hsub.undeclare()
    sub.undeclare()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_node_exits_0_within_2_s_of_a_signal(spawn, endpoint, robot, zenoh_session, sig):
    keys = Keys(robot)
    sub = LivelinessWatch(zenoh_session, keys.alive("synthetic"))
    proc = spawn("run", "synthetic", "--robot", robot, "--connect", endpoint)
    sub.expect("PUT", timeout=10)
    t0 = time.monotonic()
    proc.signal(sig)
    code = proc.wait(5)
    elapsed = time.monotonic() - t0
    assert code == 0, proc.output
    assert elapsed < 2.0, f"took {elapsed:.2f} s to stop"
    assert "Traceback" not in proc.output
    assert "Warning" not in proc.output and "WARNING" not in proc.output
    # and its liveliness token is gone with it
    sub.expect("DELETE", timeout=5)
    sub.undeclare()


def test_unreachable_settings_fail_with_a_clear_message(spawn):
    proc = spawn("run", "monitor", "--set", "topics=[sensors/nope]", "--duration", "1")
    assert proc.wait(20) == 2
    assert "unknown topic 'sensors/nope'" in proc.output


def test_clients_talk_through_a_router(spawn, endpoint, robot, tmp_path):
    """The multi-machine set-up on one host: a router, and two services in client mode."""
    summary = tmp_path / "monitor.json"
    router = spawn("run", "router", "--listen", endpoint, "--robot", robot)
    router.wait_for_output("routing on")
    client = ["--mode", "client", "--connect", endpoint, "--robot", robot]
    monitor = spawn(
        "run", "monitor", *client, "--set", f"summary={summary}", "--set", "report_period_s=0.2"
    )
    monitor.wait_for_output("monitor up")
    synthetic = spawn(
        "run", "synthetic", *client,
        "--set", "scan_rate_hz=100", "--set", "count=50", "--set", "wait_for_subscribers_s=10",
    )  # fmt: skip
    assert synthetic.wait(30) == 0, synthetic.output
    time.sleep(0.5)
    monitor.signal(signal.SIGTERM)
    assert monitor.wait(5) == 0, monitor.output
    stats = json.loads(summary.read_text())["sensors/scan"]
    assert stats["received"] == 50 and stats["lost"] == 0
    router.signal(signal.SIGINT)
    assert router.wait(5) == 0, router.output


def test_a_query_gets_the_answer_of_every_holder(endpoint, zenoh_session):
    """Two sessions answer on the same key (say the tracker and a rogue peer, each holding a
    target model): node.query's bus returns both answers, where Zenoh's default
    consolidation keeps one per key."""
    from followbot.services.runtime.bus import ZenohBus
    from followbot.services.runtime.session import open_session
    from followbot.services.runtime.settings import ZenohSettings

    key = "followbot/q/perception/target_model"
    others = [open_session(ZenohSettings(connect=[endpoint])) for _ in range(2)]
    try:
        holders = [
            zenoh_session.declare_queryable(key, lambda q: q.reply(key, b"first")),
            others[0].declare_queryable(key, lambda q: q.reply(key, b"second")),
        ]
        bus = ZenohBus(others[1])
        deadline = time.monotonic() + 10
        answers: list[bytes] = []
        while len(answers) < 2 and time.monotonic() < deadline:
            answers = bus.query(key, timeout_s=2.0)
            time.sleep(0.1)
        assert sorted(answers) == [b"first", b"second"]
        for h in holders:
            h.undeclare()
    finally:
        for s in others:
            s.close()
