"""The laser_odometry service: on the in-process fake bus (one Odometry per scan, the base's
pose through the laser mount, bad scans still answered) and as a real process over Zenoh."""

from __future__ import annotations

import contextlib
import math
import queue
import signal
import time

import numpy as np
import pytest
from odometry_room import room_scan

from followbot.schemas import Health, Keys, LaserScan, Odometry, decode, encode
from followbot.services.laser_odometry.node import LaserOdometrySettings, setup
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.clock import ClockSettings
from followbot.services.runtime.mount import LaserMount
from followbot.services.runtime.node import Node

KEYS = Keys("robot")


class Harness:
    def __init__(self, **settings) -> None:
        settings.setdefault("clock", ClockSettings(max_ahead_s=None))
        self.net = FakeNetwork()
        s = LaserOdometrySettings(**settings)
        self.node = Node("laser_odometry", s, self.net.bus("laser_odometry"))
        self.odometry = setup(self.node, s)
        self.out: list[Odometry] = []
        self.net.bus("test").subscribe(
            KEYS.topic("sensors/odom"), lambda p: self.out.append(decode(Odometry, p))
        )

    def scan(self, scan: LaserScan) -> None:
        self.net.put(KEYS.topic("sensors/scan"), encode(scan))
        self.node.spin_once()


def _base_to_laser(base, mount: LaserMount):
    """The laser's world pose for the base's world pose (W_L = W_B ∘ M)."""
    x, y, th = base
    c, s = math.cos(th), math.sin(th)
    return x + c * mount.x_m - s * mount.y_m, y + s * mount.x_m + c * mount.y_m, th + mount.yaw_rad


def test_the_base_turning_on_the_spot_is_published_as_a_turn_not_a_drive():
    # the laser sits 0.4 m ahead, turned 30°: it sweeps a circle while the base turns in place
    mount = LaserMount(x_m=0.4, y_m=0.1, yaw_deg=30.0)
    h = Harness(laser_mount=mount)
    for k in range(30):
        base = (1.0, -0.5, 0.3 + math.radians(3.0) * k)  # 30°/s
        h.scan(room_scan(_base_to_laser(base, mount), k))
    assert [m.stamp_ns for m in h.out] == [k * 100_000_000 for k in range(30)]
    last = h.out[-1]
    assert last.frame_id == "odom" and last.child_frame_id == "base_link"
    assert math.hypot(last.x_m, last.y_m) < 0.03  # the base's origin did not move
    assert math.degrees(last.yaw_rad) == pytest.approx(87.0, abs=1.0)
    assert last.w_radps == pytest.approx(math.radians(30.0), abs=math.radians(3.0))
    assert abs(last.v_mps) < 0.1


def test_the_base_driving_ahead_is_published_in_the_base_frame():
    mount = LaserMount(x_m=-0.2, y_m=0.0, yaw_deg=180.0)  # a rear laser, looking back
    h = Harness(laser_mount=mount)
    for k in range(30):
        base = (-1.0 + 0.05 * k, 0.0, 0.0)  # 0.5 m/s ahead
        h.scan(room_scan(_base_to_laser(base, mount), k))
    last = h.out[-1]
    assert (last.x_m, last.y_m) == pytest.approx((1.45, 0.0), abs=0.03)
    assert last.v_mps == pytest.approx(0.5, abs=0.1)


def test_every_scan_is_answered_even_a_refused_one():
    h = Harness()
    for k in range(5):
        h.scan(room_scan((0.0, 0.0, 0.0), k))
    scan = room_scan((0.0, 0.0, 0.0), 5)
    empty = LaserScan.from_ranges(
        np.full(len(scan.ranges_m()), np.inf, np.float32), stamp_ns=scan.stamp_ns,
        frame_id=scan.frame_id, angle_min_rad=scan.angle_min_rad,
        angle_increment_rad=scan.angle_increment_rad, range_min_m=0.02, range_max_m=20.0,
    )  # fmt: skip
    h.scan(empty)
    assert [m.stamp_ns for m in h.out][-1] == scan.stamp_ns  # lock-step: answered all the same
    assert h.odometry.counts["refused"] == 1
    h.node.run_timer("notes")
    assert "refused=1" in h.node.notes


@pytest.mark.multiprocess
def test_laser_odometry_publishes_odometry_over_zenoh(spawn, endpoint, robot, zenoh_session):
    keys = Keys(robot)
    odoms: queue.SimpleQueue = queue.SimpleQueue()
    scans: queue.SimpleQueue = queue.SimpleQueue()
    healths: queue.SimpleQueue = queue.SimpleQueue()
    subs = [
        zenoh_session.declare_subscriber(
            keys.topic("sensors/odom"), lambda s: odoms.put(decode(Odometry, s.payload.to_bytes()))
        ),
        zenoh_session.declare_subscriber(
            keys.topic("sensors/scan"), lambda s: scans.put(decode(LaserScan, s.payload.to_bytes()))
        ),
        zenoh_session.declare_subscriber(
            keys.health("laser_odometry"),
            lambda s: healths.put(decode(Health, s.payload.to_bytes())),
        ),
    ]
    lo = spawn(
        "run", "laser_odometry", "--robot", robot, "--connect", endpoint,
        "--set", "health_period_s=0.2",
    )  # fmt: skip
    lo.wait_for_output("laser_odometry up", timeout=20)
    healths.get(timeout=10)  # its session is connected
    n = 30
    synthetic = spawn(
        "run", "synthetic", "--robot", robot, "--connect", endpoint,
        "--set", "scan_rate_hz=20", "--set", f"count={n}", "--set", "odom_rate_hz=0",
        "--set", "wait_for_subscribers_s=10",
    )  # fmt: skip
    assert synthetic.wait(60) == 0, synthetic.output
    got: list[Odometry] = []
    deadline = time.monotonic() + 10
    while len(got) < n and time.monotonic() < deadline:
        with contextlib.suppress(queue.Empty):
            got.append(odoms.get(timeout=0.5))
    sent = []
    while not scans.empty():
        sent.append(scans.get().stamp_ns)
    assert len(sent) == n
    # one odometry message per scan, stamped with it; the synthetic robot stands still
    assert [m.stamp_ns for m in got] == sent, lo.output
    assert max(math.hypot(m.x_m, m.y_m) for m in got) < 0.05
    lo.signal(signal.SIGTERM)
    assert lo.wait(5) == 0
    for s in subs:
        s.undeclare()
