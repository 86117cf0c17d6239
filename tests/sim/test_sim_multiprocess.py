"""The sim service as a real process over Zenoh: with a monitor, and lock-step determinism."""

from __future__ import annotations

import json
import signal
import threading
import time
from collections import defaultdict

import pytest
from conftest import LivelinessWatch

from followbot.schemas import GroundTruth, Keys, LaserScan, decode, encode

from .helpers import controller_answer

pytestmark = pytest.mark.multiprocess


def _wait_alive(session, key: str, timeout: float = 10.0) -> None:
    watch = LivelinessWatch(session, key)
    try:
        watch.expect("PUT", timeout)
    finally:
        watch.undeclare()


def test_sim_streams_a_scenario_to_a_monitor_and_exits_0(
    spawn, endpoint, robot, tmp_path, zenoh_session
):
    summary = tmp_path / "monitor.json"
    monitor = spawn(
        "run",
        "monitor",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "topics=[sensors/scan, sensors/odom, sensors/image, sim/truth]",
        "--set",
        f"summary={summary}",
    )
    _wait_alive(zenoh_session, Keys(robot).alive("monitor"))
    sim = spawn(
        "run",
        "sim",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "scenario=thesis_5_2_2_straight",
        "--set",
        "mode=lockstep",
        "--set",
        "duration_s=3",
        "--set",
        "wait_for_subscribers=true",
    )
    assert sim.wait(60) == 0, sim.output
    assert "scenario thesis_5_2_2_straight finished at sim t=2.98 s: 25 scans" in sim.output
    assert "0 timeouts" in sim.output
    time.sleep(0.5)
    monitor.signal(signal.SIGTERM)
    assert monitor.wait(10) == 0, monitor.output
    stats = json.loads(summary.read_text())
    expected = {"sensors/scan": 25, "sim/truth": 25, "sensors/image": 30, "sensors/odom": 150}
    for topic, n in expected.items():
        assert stats[topic]["received"] == n, (topic, stats[topic], sim.output)
        assert stats[topic]["lost"] == 0 and stats[topic]["rejected"] == 0


def test_lockstep_over_zenoh_gives_a_byte_identical_stream(spawn, endpoint, robot, zenoh_session):
    """The test process plays the controller; two runs of the sim must publish the same bytes."""
    keys = Keys(robot)
    lock = threading.Lock()
    record: dict[str, list[bytes]] = defaultdict(list)
    pubs = {
        t: zenoh_session.declare_publisher(keys.topic(t))
        for t in ("control/cmd_vel", "control/pan")
    }

    def on_scan(sample) -> None:
        payload = sample.payload.to_bytes()
        with lock:
            record["sensors/scan"].append(payload)
        for topic, msg in controller_answer(decode(LaserScan, payload)):
            pubs[topic].put(encode(msg))

    def recorder(topic):
        def on_sample(sample) -> None:
            with lock:
                record[topic].append(sample.payload.to_bytes())

        return on_sample

    subs = [zenoh_session.declare_subscriber(keys.topic("sensors/scan"), on_scan)]
    for topic in ("sensors/image", "sensors/odom", "sim/truth"):
        subs.append(zenoh_session.declare_subscriber(keys.topic(topic), recorder(topic)))
    token = zenoh_session.liveliness().declare_token(keys.alive("controller"))
    runs = []
    try:
        for _ in range(2):
            with lock:
                record.clear()
            sim = spawn(
                "run",
                "sim",
                "--robot",
                robot,
                "--connect",
                endpoint,
                "--set",
                "scenario=thesis_5_2_4_two_people",
                "--set",
                "mode=lockstep",
                "--set",
                "duration_s=2",
                "--set",
                "wait_for_stages=[controller]",
                "--set",
                "lockstep_timeout_s=10",
            )
            assert sim.wait(60) == 0, sim.output
            assert "0 timeouts, 0 stray answers, 0 commands ignored" in sim.output, sim.output
            assert "17 cmd_vel, 17 pan obeyed" in sim.output, sim.output
            time.sleep(0.3)
            with lock:
                runs.append({k: list(v) for k, v in record.items()})
    finally:
        token.undeclare()
        for s in subs:
            s.undeclare()
        for p in pubs.values():
            p.undeclare()
    counts = {k: len(v) for k, v in runs[0].items()}
    assert counts == {"sensors/scan": 17, "sensors/image": 20, "sensors/odom": 100, "sim/truth": 17}
    assert runs[0] == runs[1]
    # and the loop was closed: the robot drove on the controller's commands
    last = decode(GroundTruth, runs[0]["sim/truth"][-1])
    assert last.robot_x_m > 0.2


def test_a_broken_scenario_exits_2_naming_the_fault(spawn, endpoint, tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: b\npeople: [{id: 1, start: [2, fast]}]\n")
    proc = spawn("run", "sim", "--connect", endpoint, "--set", f"scenario={broken}")
    assert proc.wait(30) == 2, proc.output
    assert "broken.yaml" in proc.output
    assert "$.people[0].start[1]" in proc.output
    proc = spawn("run", "sim", "--connect", endpoint, "--set", "scenario=no_such_one")
    assert proc.wait(30) == 2, proc.output
    assert "unknown scenario 'no_such_one'; built-in scenarios:" in proc.output
