"""Fault injection (`make chaos`, opt-in, a few minutes): the whole system under `followbot up`
while each service is killed in turn and a rogue peer sends garbage and stamps from the wrong
time on every topic the services read.

Prints: services crashed (must be 0), the longest time the robot moved without a fresh target
(must be <= 0.5 s), the share of good scans answered by the tracker while the stages that
answer them were up (must be >= 99 %), inputs rejected and counted, restarts.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
import pytest
import yaml

from followbot.schemas import (
    Array,
    GroundTruth,
    Health,
    Image,
    Keys,
    LaserScan,
    Odometry,
    PanCommand,
    PersonCandidates,
    RejectedMessage,
    TrackState,
    VelocityCommand,
    Verification,
    decode,
    encode,
)

pytestmark = [pytest.mark.chaos, pytest.mark.multiprocess]

STAGES = ["laser_legs", "vision_verify", "tracker", "controller"]
KILL_ORDER = ["laser_legs", "tracker", "controller", "vision_verify", "sim"]
KILL_EVERY_S = float(os.environ.get("FOLLOWBOT_CHAOS_KILL_EVERY_S", "14"))
WARMUP_S = 12.0
# a restarted stage answers again once it is alive and has had this long to settle
SETTLE_S = 3.0
HOUR_NS = 3600 * 10**9


SCENARIO = """\
name: chaos_circle
description: The target walks round and round a 2 m circle in a large room; the robot follows.
duration_s: 3600.0
seed: 5
world:
  walls:
    - points: [[-1.5, -5.0], [9.5, -5.0], [9.5, 5.0], [-1.5, 5.0]]
      closed: true
robot:
  start: [2.0, -2.0]
  yaw_deg: 0.0
people:
  - id: 1
    is_target: true
    start: [4.0, -2.0]
    heading_deg: 0.0
    speed_mps: 0.6
    loop: true
    path:
      - {kind: arc, centre: [4.0, 0.0], sweep_deg: 360.0}
    appearance:
      shirt_rgb: [200, 40, 40]
      trousers_rgb: [40, 50, 90]
"""


def compose_file(path, robot: str, endpoint: str, duration_s: float) -> None:
    scenario = path.parent / "chaos_circle.yaml"
    scenario.write_text(SCENARIO)
    client = {"mode": "client", "connect": [endpoint]}
    doc = {
        "name": "chaos",
        "robot": robot,
        "preset": "thesis",
        "services": {
            "router": {
                "settings": {"zenoh": {"mode": "router", "connect": [], "listen": [endpoint]}}
            },
            "sim": {
                "settings": {
                    "scenario": str(scenario),
                    "duration_s": duration_s,
                    "mode": "realtime",
                    "wait_for_stages": STAGES,
                    "zenoh": client,
                },
                "stop_all_on_exit": True,
            },
            "laser_legs": {"settings": {"zenoh": client}},
            "vision_verify": {"settings": {"zenoh": client, "acquire": {"auto": True}}},
            # the first target by the laser (vision would wait for a model first)
            "tracker": {"settings": {"zenoh": client, "acquire": "nearest"}},
            "controller": {"settings": {"zenoh": client}},
        },
    }
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


@dataclass
class Observed:
    """What the test's own session saw, with wall-clock arrival times (monotonic s)."""

    scans: list[tuple[float, int]] = field(default_factory=list)
    answered: set[int] = field(default_factory=set)
    fresh_targets: list[float] = field(default_factory=list)
    motion: list[tuple[float, float, float]] = field(default_factory=list)  # t, v, w
    pids: dict[str, int] = field(default_factory=dict)
    rejected: dict[tuple[str, int], int] = field(default_factory=dict)  # (service, pid) -> n
    alive_at: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    newest_stamp: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def plausible(self, stamp: int) -> bool:
        """A stamp of the simulator's clock (the rogue's are hours off)."""
        return abs(stamp - self.newest_stamp) < 10 * 10**9 or self.newest_stamp == 0


class Observer:
    def __init__(self, session, keys: Keys) -> None:
        import zenoh

        self.o = Observed()
        self._last_target_stamp = None
        subs = []

        def on(topic, kind, fn):
            def cb(sample):
                try:
                    m = decode(kind, sample.payload.to_bytes())
                except RejectedMessage:
                    return  # the rogue's garbage
                with self.o.lock:
                    fn(time.monotonic(), m)

            subs.append(session.declare_subscriber(keys.topic(topic), cb))

        on("sensors/scan", LaserScan, self._scan)
        on("tracking/target", TrackState, self._target)
        on("sim/truth", GroundTruth, self._truth)

        def health(sample):
            try:
                h = decode(Health, sample.payload.to_bytes())
            except RejectedMessage:
                return
            with self.o.lock:
                self.o.pids[h.service] = h.pid
                self.o.rejected[(h.service, h.pid)] = sum(h.rejected.values())

        subs.append(session.declare_subscriber(f"{keys.root}/health/*", health))

        def alive(sample):
            if sample.kind == zenoh.SampleKind.PUT:
                service = str(sample.key_expr).rsplit("/", 1)[-1]
                with self.o.lock:
                    self.o.alive_at[service].append(time.monotonic())

        subs.append(session.liveliness().declare_subscriber(f"{keys.root}/alive/*", alive))
        self._subs = subs

    def _scan(self, t: float, m: LaserScan) -> None:
        if self.o.newest_stamp == 0 or self.o.plausible(m.stamp_ns) or m.stamp_ns < 10**9:
            # (a restarted simulator starts again near 0)
            self.o.newest_stamp = m.stamp_ns
            self.o.scans.append((t, m.stamp_ns))

    def _target(self, t: float, m: TrackState) -> None:
        if not self.o.plausible(m.stamp_ns):
            return
        self.o.answered.add(m.stamp_ns)
        if m.status in ("tracking", "coasting") and m.stamp_ns != self._last_target_stamp:
            self.o.fresh_targets.append(t)
        self._last_target_stamp = m.stamp_ns

    def _truth(self, t: float, m: GroundTruth) -> None:
        if self.o.plausible(m.stamp_ns):
            self.o.motion.append((t, m.robot_v_mps, m.robot_w_radps))


class Rogue:
    """Garbage, truncated payloads and stamps from the wrong time on every topic a service
    reads, a burst every ``period_s``."""

    def __init__(self, session, keys: Keys, observed: Observed, period_s: float = 0.5) -> None:
        self.o = observed
        self.period_s = period_s
        self.sent = 0
        self._pubs = {t: session.declare_publisher(keys.topic(t)) for t in self.topics()}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._rng = np.random.default_rng(7)

    @staticmethod
    def topics() -> list[str]:
        return [
            "sensors/scan", "sensors/image", "sensors/odom", "perception/candidates",
            "perception/verification", "perception/target_model", "perception/target_command",
            "tracking/target", "control/cmd_vel", "control/pan",
        ]  # fmt: skip

    def messages(self, topic: str, stamp: int) -> list[bytes]:
        """Valid messages of ``topic`` stamped ``stamp`` (target commands: none -- a valid
        command from anyone is what access control is for, docs/compose.md)."""
        ranges = Array.from_numpy(np.full(181, 3.0, dtype=np.float32))
        make = {
            "sensors/scan": lambda: LaserScan(
                stamp_ns=stamp, angle_min_rad=-1.57, angle_increment_rad=0.01745,
                range_min_m=0.05, range_max_m=30.0, ranges=ranges,
            ),
            "sensors/image": lambda: Image.from_array(
                np.zeros((240, 320, 3), np.uint8), stamp_ns=stamp
            ),
            "sensors/odom": lambda: Odometry(stamp_ns=stamp, x_m=5.0, y_m=5.0, yaw_rad=1.0),
            "perception/candidates": lambda: PersonCandidates(stamp_ns=stamp),
            "perception/verification": lambda: Verification(stamp_ns=stamp),
            "tracking/target": lambda: TrackState(
                stamp_ns=stamp, status="tracking", x_m=0.5, y_m=0.0
            ),
            "control/cmd_vel": lambda: VelocityCommand(
                stamp_ns=stamp, linear_mps=0.7, angular_radps=1.0
            ),
            "control/pan": lambda: PanCommand(stamp_ns=stamp, pan_rad=1.0),
        }  # fmt: skip
        if topic not in make:
            return []
        try:
            return [encode(make[topic]())]
        except (TypeError, ValueError):
            return []

    def burst(self) -> None:
        with self.o.lock:
            now = self.o.newest_stamp
        for topic, pub in self._pubs.items():
            payloads = [b"", b"\xc1garbage", bytes(self._rng.integers(0, 256, 64, np.uint8))]
            for stamp in (now + HOUR_NS, 2**63 - 1, max(0, now - HOUR_NS), now + 5 * 10**9):
                for p in self.messages(topic, stamp):
                    payloads += [p, p[: len(p) // 2]]
            if topic == "control/cmd_vel":  # beyond any base's bounds, and not a number
                for v, w in ((1e12, 0.0), (0.5, float("nan"))):
                    payloads.append(
                        encode(VelocityCommand(stamp_ns=now, linear_mps=v, angular_radps=w))
                    )
            for p in payloads:
                pub.put(p)
                self.sent += 1

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.burst()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def test_the_system_survives_kills_garbage_and_bad_clocks(tmp_path, endpoint, robot):
    from followbot.services.runtime.session import open_session
    from followbot.services.runtime.settings import ZenohSettings

    duration = WARMUP_S + KILL_EVERY_S * len(KILL_ORDER) + 10.0
    compose = tmp_path / "chaos.yaml"
    compose_file(compose, robot, endpoint, duration + 120.0)
    log = (tmp_path / "up.log").open("w")
    up = subprocess.Popen(
        [sys.executable, "-m", "followbot", "up", str(compose), "--log-dir", str(tmp_path / "up")],
        stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )  # fmt: skip
    keys = Keys(robot)
    time.sleep(1.0)  # the router first
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    kills: list[tuple[str, float]] = []
    try:
        obs = Observer(session, keys)
        o = obs.o
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not o.fresh_targets:
            time.sleep(0.2)
        assert o.fresh_targets, "the robot never started following: " + up_log(tmp_path)
        rogue = Rogue(session, keys, o)
        rogue.start()
        time.sleep(WARMUP_S)
        for service in KILL_ORDER:
            wait_until_moving(o, timeout_s=15.0)  # the worst moment to lose a stage
            with o.lock:
                pid = o.pids.get(service)
            assert pid, f"no pid of {service} in its health"
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                raise AssertionError(f"{service} (pid {pid}) is gone: {up_log(tmp_path)}") from None
            kills.append((service, time.monotonic()))
            time.sleep(KILL_EVERY_S)
        rogue.stop()
        time.sleep(2.0)
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(30)
        except subprocess.TimeoutExpired:
            up.kill()
        session.close()
        log.close()
    out = up_log(tmp_path)
    fig = figures(o, kills, out, rogue.sent)
    print("\nchaos: " + ", ".join(f"{k} {v}" for k, v in fig.items()))
    assert fig["services crashed"] == 0, out[-3000:]
    assert fig["restarts"] >= len(KILL_ORDER), out[-3000:]
    assert fig["longest moving without a fresh target (s)"] <= 0.5
    assert fig["good scans answered (%)"] >= 99.0
    assert fig["inputs rejected and counted"] > 0


def wait_until_moving(o: Observed, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with o.lock:
            if o.motion and o.motion[-1][1] > 0.3:
                return
        time.sleep(0.05)


def up_log(tmp_path) -> str:
    return (tmp_path / "up.log").read_text()


def figures(o: Observed, kills: list[tuple[str, float]], out: str, rogue_sent: int) -> dict:
    # crashes: any exit that was not one of our SIGKILLs (up says "exited -9" for those)
    exits = re.findall(r"^(\S+)\s*\| (\S+) exited (-?\d+)", out, re.M)
    crashed = [(s, c) for _, s, c in exits if c not in ("-9", "0")]
    restarts = len(re.findall(r"restarting in", out))
    # moving without a fresh target: the robot's true speed against the newest fresh target
    fresh = np.array(o.fresh_targets)
    longest = 0.0
    after_kill = dict.fromkeys((s for s, _ in kills), 0.0)
    for t, v, w in o.motion:
        k = np.searchsorted(fresh, t) - 1
        if k >= 0 and (abs(v) > 0.02 or abs(w) > 0.05):
            longest = max(longest, t - fresh[k])
            for service, t_kill in kills:
                if t_kill <= t <= t_kill + 5.0:
                    after_kill[service] = max(after_kill[service], round(t - fresh[k], 3))
    # good scans answered, outside the windows where a stage of the answer chain was down
    down: list[tuple[float, float]] = []
    for service, t_kill in kills:
        if service in ("laser_legs", "tracker", "sim"):
            back = [t for t in o.alive_at.get(service, []) if t > t_kill]
            t_back = (back[0] if back else float("inf")) + SETTLE_S
            down.append((t_kill, t_back))
    t_first = o.fresh_targets[0] if o.fresh_targets else 0.0
    judged = [s for t, s in o.scans[:-20] if t > t_first and not any(a <= t <= b for a, b in down)]
    answered = sum(1 for s in judged if s in o.answered)
    share = 100.0 * answered / max(1, len(judged))
    return {
        "services crashed": len(crashed),
        "kills": len(kills),
        "restarts": restarts,
        "longest moving without a fresh target (s)": round(longest, 3),
        "... after each kill (s)": after_kill,
        "good scans answered (%)": round(share, 2),
        "scans judged": len(judged),
        "inputs rejected and counted": sum(o.rejected.values()),
        "rogue messages sent": rogue_sent,
    }


if __name__ == "__main__":
    raise SystemExit(pytest.main([__file__, "-s", "--run-chaos", *sys.argv[1:]]))
