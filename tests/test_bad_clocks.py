"""Bad clocks against real processes: a stamp from the future, stamps that stand still, a
source that starts again from an earlier time. The stages reject what cannot be true, keep
answering the honest stream, start afresh after a real restart, and the robot stops when the
target's estimate stops being fed."""

from __future__ import annotations

import math
import queue
import threading
import time

import numpy as np
import pytest

from followbot.schemas import (
    Array,
    Candidate,
    Health,
    Image,
    Keys,
    LaserScan,
    Odometry,
    PersonCandidates,
    TrackState,
    VelocityCommand,
    decode,
    encode,
)

pytestmark = pytest.mark.multiprocess

HOUR_NS = 3600 * 10**9


class Source:
    """A still robot and one person 2.6 m ahead: odometry, scan and candidates, 20 a second,
    stamped by ``clock()`` (the test changes it while it runs)."""

    def __init__(self, session, keys: Keys) -> None:
        self.pubs = {
            t: session.declare_publisher(keys.topic(t))
            for t in ("sensors/odom", "sensors/scan", "perception/candidates")
        }
        self.clock = time.time_ns
        self.sent: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.ranges = np.full(181, 6.0, dtype=np.float32)

    def put(self, stamp: int) -> None:
        self.pubs["sensors/odom"].put(
            encode(Odometry(stamp_ns=stamp, x_m=0.0, y_m=0.0, yaw_rad=0.0))
        )
        self.pubs["sensors/scan"].put(
            encode(
                LaserScan(
                    stamp_ns=stamp,
                    angle_min_rad=-math.pi / 2,
                    angle_increment_rad=math.pi / 180,
                    range_min_m=0.05,
                    range_max_m=30.0,
                    ranges=Array.from_numpy(self.ranges),
                )
            )
        )
        c = Candidate(
            x_m=2.6, y_m=0.2, range_m=math.hypot(2.6, 0.2), bearing_rad=math.atan2(0.2, 2.6)
        )
        self.pubs["perception/candidates"].put(
            encode(PersonCandidates(stamp_ns=stamp, candidates=[c]))
        )

    def _run(self) -> None:
        while not self._stop.is_set():
            stamp = self.clock()
            self.put(stamp)
            self.sent.append(stamp)
            time.sleep(0.05)

    def __enter__(self) -> Source:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


class Listen:
    """Every message of one topic, with its arrival time."""

    def __init__(self, session, key: str, kind) -> None:
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.all: list = []
        self._sub = session.declare_subscriber(
            key, lambda s: self.q.put((time.monotonic(), decode(kind, s.payload.to_bytes())))
        )

    def until(self, pred, timeout: float = 15.0):
        """The first message from now on for which ``pred(msg)`` holds (fails after timeout)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                t, m = self.q.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                break
            self.all.append(m)
            if pred(m):
                return t, m
        raise AssertionError(f"nothing matched within {timeout} s; last: {self.all[-3:]}")


def start_pipeline(spawn, endpoint, robot):
    common = ["--robot", robot, "--connect", endpoint, "--set", "health_period_s=0.25"]
    tracker = spawn("run", "tracker", *common, "--set", "acquire=nearest")
    controller = spawn("run", "controller", *common)
    tracker.wait_for_output("tracker up", timeout=30)
    controller.wait_for_output("controller up", timeout=30)
    return tracker, controller


def test_a_scan_stamped_an_hour_ahead_or_at_the_end_of_time_freezes_nothing(
    spawn, endpoint, robot, zenoh_session
):
    keys = Keys(robot)
    targets = Listen(zenoh_session, keys.topic("tracking/target"), TrackState)
    health = Listen(zenoh_session, keys.health("tracker"), Health)
    tracker, _ = start_pipeline(spawn, endpoint, robot)
    with Source(zenoh_session, keys) as src:
        targets.until(lambda m: m.status == "tracking", timeout=20)
        now = time.time_ns()
        src.put(now + HOUR_NS)  # one message of each input an hour ahead
        src.put(2**63 - 1)  # and at the end of time
        time.sleep(0.3)
        after = time.time_ns()
        # the honest stream goes on being answered and the target stays tracked
        _, m = targets.until(lambda m: m.stamp_ns > after, timeout=5)
        assert m.status == "tracking" and "out_of_order" not in m.flags, m
        for _ in range(10):
            _, m = targets.until(lambda m: True, timeout=2)
            assert m.status == "tracking" and m.stamp_ns < now + HOUR_NS, m
        _, h = health.until(lambda h: h.rejected.get("perception/candidates", 0) >= 2)
        assert h.rejected["sensors/odom"] >= 2
    assert tracker.p.poll() is None


def test_stamps_that_stand_still_stop_the_robot(spawn, endpoint, robot, zenoh_session):
    keys = Keys(robot)
    targets = Listen(zenoh_session, keys.topic("tracking/target"), TrackState)
    cmds = Listen(zenoh_session, keys.topic("control/cmd_vel"), VelocityCommand)
    health = Listen(zenoh_session, keys.health("tracker"), Health)
    start_pipeline(spawn, endpoint, robot)
    with Source(zenoh_session, keys) as src:
        cmds.until(lambda c: c.linear_mps > 0.3, timeout=20)  # following
        frozen = time.time_ns()
        src.clock = lambda: frozen  # the source's clock stops; its messages go on
        t_frozen = time.monotonic()
        t_lost, lost = targets.until(lambda m: m.status == "lost", timeout=5)
        assert "stale_input" in lost.flags and t_lost - t_frozen < 2.0
        t_stop, _ = cmds.until(lambda c: c.linear_mps == 0.0 and c.angular_radps == 0.0)
        assert t_stop - t_frozen < 2.5
        # and it stays stopped while the stamps stand still
        time.sleep(1.0)
        while not cmds.q.empty():
            _, c = cmds.q.get()
            assert c.linear_mps == 0.0, c
        _, h = health.until(lambda h: h.status != "ok")
        assert any("out of order" in r for r in h.reasons), h.reasons


def test_a_source_that_starts_again_an_hour_earlier_is_followed_afresh(
    spawn, endpoint, robot, zenoh_session
):
    keys = Keys(robot)
    targets = Listen(zenoh_session, keys.topic("tracking/target"), TrackState)
    start_pipeline(spawn, endpoint, robot)
    with Source(zenoh_session, keys) as src:
        targets.until(lambda m: m.status == "tracking", timeout=20)
        src.clock = lambda: time.time_ns() - HOUR_NS  # a bag looping back an hour
        restart = time.time_ns() - HOUR_NS
        # within a few scans the stages take the new clock and track the person again
        t0 = time.monotonic()
        targets.until(lambda m: m.stamp_ns >= restart and m.status == "tracking")
        assert time.monotonic() - t0 < 3.0


def test_an_image_stamped_in_the_future_does_not_blind_vision(
    spawn, endpoint, robot, zenoh_session
):
    keys = Keys(robot)
    health = Listen(zenoh_session, keys.health("vision_verify"), Health)
    proc = spawn(
        "run", "vision_verify", "--robot", robot, "--connect", endpoint,
        "--set", "health_period_s=0.25",
    )  # fmt: skip
    proc.wait_for_output("vision_verify up", timeout=30)
    pub = zenoh_session.declare_publisher(keys.topic("sensors/image"))
    px = np.full((240, 320, 3), 90, dtype=np.uint8)

    def image(stamp: int) -> bytes:
        return encode(Image.from_array(px, stamp_ns=stamp))

    for _ in range(10):
        pub.put(image(time.time_ns()))
        time.sleep(0.1)
    pub.put(image(time.time_ns() + HOUR_NS))
    # sensors/image is a latest-only input: an image that arrives before the loop has taken
    # the one before replaces it unjudged. Sent back to back, the next image superseded the
    # future one on a loaded machine (rejected 0): send the rest once it has been judged.
    health.until(lambda h: h.rejected.get("sensors/image", 0) >= 1, timeout=10)
    for _ in range(20):
        pub.put(image(time.time_ns()))
        time.sleep(0.1)
    _, h = health.until(lambda h: h.received.get("sensors/image", 0) >= 28, timeout=10)
    # one rejection (the future image), not one per later image
    assert h.rejected["sensors/image"] == 1, h
    assert not any("out_of_order" in n for n in h.notes), h.notes
