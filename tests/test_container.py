"""Several services in one process (``followbot run a+b+c``): settings, in-process delivery,
and the three robot-side stages as one real process over Zenoh."""

from __future__ import annotations

import collections
import signal
import threading
import time

import pytest

from followbot.bench_pipeline import scan_bank
from followbot.schemas import (
    Keys,
    Odometry,
    PersonCandidates,
    TrackState,
    VelocityCommand,
    decode,
    encode,
)
from followbot.services.runtime.container import LocalHub, split_settings
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import NodeSettings, SettingsError

from .conftest import LivelinessWatch

GROUP = ["laser_legs", "tracker", "controller"]


def test_group_settings_are_shared_unless_a_service_section_or_prefix_says_otherwise():
    data = {"robot": "r2", "log_level": "warning", "tracker": {"estimator": "ukf"}}
    shared, merged = split_settings(
        GROUP, data, ["laser_legs.detector=learned", "health_period_s=2", "tracker.seed=3"]
    )
    assert shared == {"robot": "r2", "log_level": "warning", "health_period_s": 2}
    assert merged["tracker"] == {**shared, "estimator": "ukf", "seed": 3}
    assert merged["laser_legs"] == {**shared, "detector": "learned"}
    assert merged["controller"] == shared
    with pytest.raises(SettingsError, match=r"tracker\.zenoh: .*share one Zenoh session"):
        split_settings(GROUP, {"tracker": {"zenoh": {"mode": "client"}}}, [])
    with pytest.raises(SettingsError, match="expected a mapping"):
        split_settings(GROUP, {"tracker": [1, 2]}, [])


def test_bad_group_commands_exit_2_with_the_reason(spawn):
    p = spawn("run", "laser_legs+trackr")
    assert p.wait(30) == 2 and "unknown service 'trackr'" in p.output
    p = spawn("run", "tracker+controller", "--set", "tracker.estimator=nope")
    assert p.wait(30) == 2 and "nope" in p.output


def test_a_message_reaches_a_node_of_the_same_process_in_the_publishing_thread(endpoint):
    from followbot.services.runtime.session import open_session
    from followbot.services.runtime.settings import ZenohSettings

    with open_session(ZenohSettings(listen=[endpoint])) as session:
        hub = LocalHub(session)
        a = Node("a", NodeSettings(robot="hubtest"), hub.bus())
        b = Node("b", NodeSettings(robot="hubtest"), hub.bus())
        got: list[tuple[int, int]] = []
        b.subscribe("tracking/target", lambda m: got.append((threading.get_ident(), m.stamp_ns)))
        pub = a.publisher("tracking/target")
        assert pub.matching()  # an in-process subscriber is a match
        pub.put(TrackState(stamp_ns=42, status="tracking"))
        assert got == [(threading.get_ident(), 42)]  # delivered before put returned
        time.sleep(0.3)
        assert got == [(threading.get_ident(), 42)]  # and not a second time through Zenoh
        a.close()
        b.close()


@pytest.mark.multiprocess
def test_laser_legs_tracker_and_controller_in_one_process(spawn, endpoint, robot, zenoh_session):
    """Scans in, velocity commands out, every service alive on its own token, each message
    published to the network once, and a clean exit on SIGTERM."""
    keys = Keys(robot)
    watches = [LivelinessWatch(zenoh_session, keys.alive(s)) for s in GROUP]
    seen: dict[str, collections.Counter] = {
        t: collections.Counter()
        for t in ("perception/candidates", "tracking/target", "control/cmd_vel")
    }
    types = {
        "perception/candidates": PersonCandidates,
        "tracking/target": TrackState,
        "control/cmd_vel": VelocityCommand,
    }
    last: dict[str, object] = {}

    def watcher(topic):
        def on_sample(sample) -> None:
            msg = decode(types[topic], sample.payload.to_bytes())
            seen[topic][msg.stamp_ns] += 1
            last[topic] = msg

        return on_sample

    subs = [zenoh_session.declare_subscriber(keys.topic(t), watcher(t)) for t in seen]
    group = spawn(
        "run", "+".join(GROUP), "--robot", robot, "--connect", endpoint,
        "--set", "tracker.acquire=nearest",
    )  # fmt: skip
    for w in watches:
        w.expect("PUT", timeout=30)
    scans = zenoh_session.declare_publisher(keys.topic("sensors/scan"))
    odom = zenoh_session.declare_publisher(keys.topic("sensors/odom"))
    time.sleep(0.5)  # the group's subscriptions reach this session
    stamps = []
    for scan in scan_bank(1, 60, rate_hz=20.0):
        stamp = time.monotonic_ns()
        odom.put(encode(Odometry(stamp_ns=stamp, x_m=0.0, y_m=0.0, yaw_rad=0.0)))
        scan.stamp_ns = stamp
        scans.put(encode(scan))
        stamps.append(stamp)
        time.sleep(0.05)
    time.sleep(0.5)
    assert last["tracking/target"].status == "tracking"
    time.sleep(1.0)
    # the scans stopped: past stale_after_s (1 s) the tracker said once that the target is
    # lost, naming the last scan; every other scan had one answer on each topic
    stale = last["tracking/target"]
    assert stale.status == "lost" and "stale_input" in stale.flags and stale.stamp_ns == stamps[-1]
    seen["tracking/target"][stamps[-1]] -= 1
    for topic, counts in seen.items():
        answered = [s for s in stamps if counts[s]]
        assert len(answered) >= len(stamps) - 2, (topic, len(answered), group.output[-2000:])
        if topic != "control/cmd_vel":  # (the controller's watchdog repeats itself)
            assert max(counts.values()) == 1, f"{topic} published twice for one scan"
    group.signal(signal.SIGTERM)
    assert group.wait(15) == 0, group.output[-2000:]
    for w in watches:
        w.expect("DELETE", timeout=10)
        w.undeclare()
    for s in subs:
        s.undeclare()
