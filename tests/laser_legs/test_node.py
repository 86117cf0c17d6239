"""The laser_legs service: on the in-process fake bus (criterion 3, stamps, settings) and as a
real process between the synthetic publisher and the test's own Zenoh subscriber."""

from __future__ import annotations

import contextlib
import math
import queue
import signal
import time

import msgspec
import pytest

from followbot.schemas import (
    Health,
    Keys,
    Odometry,
    PersonCandidates,
    TrackState,
    decode,
    encode,
)
from followbot.services.laser_legs.node import LaserLegsSettings, setup
from followbot.services.laser_legs.prediction import TargetPredictor
from followbot.services.laser_legs.scene import make_scan, person_legs
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.clock import ClockSettings
from followbot.services.runtime.mount import LaserMount
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import SettingsError, load_settings

KEYS = Keys("robot")
WALL = [(3.0, -3.0, 3.0, 3.0), (3.0, 3.0, -3.0, 3.0), (-3.0, -3.0, 3.0, -3.0)]
MS = 1_000_000


def two_people(stamp_ns: int):
    return make_scan(
        person_legs(1.5, 0.8) + person_legs(1.5, -0.8),
        WALL,
        stamp_ns=stamp_ns,
        fov_rad=math.radians(180),
    )


def target(stamp_ns: int, x: float, y: float, status="tracking", vx=0.0, vy=0.0, frame="base_link"):
    return TrackState(
        stamp_ns=stamp_ns, frame_id=frame, status=status, x_m=x, y_m=y, vx_mps=vx, vy_mps=vy
    )


class Harness:
    def __init__(self, **settings) -> None:
        # the tests' stamps step faster than the tests' own clock: no stamp is "ahead"
        settings.setdefault("clock", ClockSettings(max_ahead_s=None))
        self.net = FakeNetwork()
        self.node = Node("laser_legs", LaserLegsSettings(**settings), self.net.bus("laser_legs"))
        self.predictor = setup(self.node, self.node.settings)
        self.out: list[PersonCandidates] = []
        self.net.bus("test").subscribe(
            KEYS.topic("perception/candidates"),
            lambda p: self.out.append(decode(PersonCandidates, p)),
        )

    def put(self, topic: str, message) -> None:
        self.net.put(KEYS.topic(topic), encode(message))
        self.node.spin_once()


def test_one_candidates_message_per_scan_with_its_stamp():
    h = Harness()
    stamps = [5 * MS, 125 * MS, 245 * MS]
    for t in stamps:
        h.put("sensors/scan", two_people(t))
    h.put("sensors/scan", make_scan([], [], stamp_ns=300 * MS))  # nothing there: still one
    assert [m.stamp_ns for m in h.out] == [*stamps, 300 * MS]
    assert [len(m.candidates) for m in h.out] == [2, 2, 2, 0]
    assert all(m.detector == "thesis" and m.frame_id == "base_laser" for m in h.out)


def test_criterion_3_gates_on_a_recent_tracked_target_only():
    h = Harness()
    h.put("tracking/target", target(100 * MS, 1.5, 0.8))
    h.put("sensors/scan", two_people(220 * MS))
    assert len(h.out[-1].candidates) == 1 and h.out[-1].candidates[0].y_m > 0
    # a target that is not tracked does not gate
    h.put("tracking/target", target(220 * MS, 1.5, 0.8, status="lost"))
    h.put("sensors/scan", two_people(340 * MS))
    assert len(h.out[-1].candidates) == 2
    # a stale one neither (older than prediction_max_age_s = 0.5 s)
    h.put("tracking/target", target(340 * MS, 1.5, -0.8))
    h.put("sensors/scan", two_people(900 * MS))
    assert len(h.out[-1].candidates) == 2
    # nor one stamped after the scan
    h.put("tracking/target", target(2000 * MS, 1.5, -0.8))
    h.put("sensors/scan", two_people(1000 * MS))
    assert len(h.out[-1].candidates) == 2
    # velocity carries the prediction onto the other person: 1.6 m in 0.4 s
    h.put("tracking/target", target(1100 * MS, 1.5, 0.8, vy=-4.0))
    h.put("sensors/scan", two_people(1500 * MS))
    (c,) = h.out[-1].candidates
    assert c.y_m < 0
    assert h.predictor.used == 2


def test_criterion_3_compensates_ego_motion():
    h = Harness()
    # the robot turned left by 90 deg on the spot between the target's stamp and the scan's
    h.put("sensors/odom", Odometry(stamp_ns=0, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    h.put("sensors/odom", Odometry(stamp_ns=200 * MS, x_m=0.0, y_m=0.0, yaw_rad=math.pi / 2))
    # the person at (1.5, 0.8) in the new frame is at R(+90) (1.5, 0.8) = (-0.8, 1.5) in the old
    h.put("tracking/target", target(0, -0.8, 1.5))
    h.put("sensors/scan", two_people(200 * MS))
    (c,) = h.out[-1].candidates
    assert math.hypot(c.x_m - 1.5, c.y_m - 0.8) < 0.1
    # odometry known, but not at the scan's stamp (beyond extrapolation): no gating at all
    h.put("tracking/target", target(200 * MS, 1.5, 0.8))
    h.put("sensors/scan", two_people(600 * MS))
    assert len(h.out[-1].candidates) == 2
    assert h.predictor.skipped == 1


def test_late_odometry_takes_its_place_and_criterion_3_still_compensates():
    """Odometry delivered out of order (within the clock guard's tolerance) joins the history
    at its stamp: the poses at the target's and the scan's stamps stay known."""
    h = Harness()
    h.put("sensors/odom", Odometry(stamp_ns=0, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    h.put("sensors/odom", Odometry(stamp_ns=200 * MS, x_m=0.0, y_m=0.0, yaw_rad=math.pi / 2))
    h.put("sensors/odom", Odometry(stamp_ns=100 * MS, x_m=0.0, y_m=0.0, yaw_rad=math.pi / 4))
    h.put("tracking/target", target(0, -0.8, 1.5))  # (1.5, 0.8) before the 90 deg turn
    h.put("sensors/scan", two_people(200 * MS))
    (c,) = h.out[-1].candidates
    assert math.hypot(c.x_m - 1.5, c.y_m - 0.8) < 0.1
    assert (h.predictor.used, h.predictor.skipped) == (1, 0)


def test_a_coasting_target_does_not_gate_the_legs():
    """A target the tracker has missed may be anywhere near its prediction, or the prediction
    may be a rollback's old snapshot: gating on it (0.4 m) deleted the target's own legs and lost
    it (ristic_circles, the target 0.5 m from the robot). Only a tracked target gates."""
    h = Harness()
    h.put("tracking/target", target(100 * MS, 1.5, 0.8))
    h.put("sensors/scan", two_people(200 * MS))
    assert len(h.out[-1].candidates) == 1  # tracking: only the target's legs
    h.put("tracking/target", target(200 * MS, 1.5, 0.8, status="coasting"))
    h.put("sensors/scan", two_people(300 * MS))
    assert len(h.out[-1].candidates) == 2  # coasting: every leg, the tracker gates itself
    h.put("tracking/target", target(300 * MS, 1.5, 0.8))
    h.put("sensors/scan", two_people(400 * MS))
    assert len(h.out[-1].candidates) == 1


def test_prediction_can_be_switched_off():
    h = Harness(use_target_prediction=False)
    h.put("tracking/target", target(100 * MS, 1.5, 0.8))
    h.put("sensors/scan", two_people(200 * MS))
    assert len(h.out[-1].candidates) == 2


def test_the_laser_mount_turns_the_base_frame_target_into_the_scan_s_frame():
    """The tracker's target is in the base frame; the gate is in the laser frame of the scan:
    a laser 0.5 m ahead and turned 90 deg left sees a person 2 m ahead, 0.8 m left at 0.8 m
    to its right and 1.5 m out."""
    h = Harness(laser_mount=LaserMount(x_m=0.5, y_m=0.0, yaw_deg=90.0))
    h.put("tracking/target", target(0, 2.0, 0.8))
    assert h.predictor.predict(two_people(100 * MS)) == pytest.approx((0.8, -1.5))
    assert Harness().predictor.predict(two_people(100 * MS)) is None  # no target yet
    still = TargetPredictor()
    still.add_target(target(0, 2.0, 0.8, frame="base_laser"))  # the frame's name changes nothing
    assert still.predict(two_people(100 * MS)) == pytest.approx((2.0, 0.8))


@pytest.mark.parametrize("gated", [True, False])
def test_the_detector_gets_the_laser_s_odometry_pose_at_each_scan(monkeypatch, gated):
    """The laser's pose in the odometry frame (odometry * laser_mount, interpolated at the
    scan's stamp) goes to the detector with each scan, also with criterion 3 off; none
    before any odometry."""
    from followbot.services.laser_legs.detectors.thesis import ClusterLegDetector

    poses = []
    inner = ClusterLegDetector.detect
    monkeypatch.setattr(
        ClusterLegDetector,
        "detect",
        lambda self, s, p=None, pose=None: poses.append(pose) or inner(self, s, p),
    )
    mount = LaserMount(x_m=0.5, y_m=0.0, yaw_deg=90.0)
    h = Harness(laser_mount=mount, use_target_prediction=gated)
    h.put("sensors/scan", two_people(50 * MS))
    h.put("sensors/odom", Odometry(stamp_ns=100 * MS, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    h.put("sensors/odom", Odometry(stamp_ns=300 * MS, x_m=1.0, y_m=2.0, yaw_rad=math.pi / 2))
    h.put("sensors/scan", two_people(200 * MS))
    assert poses[0] is None
    # halfway: the base at (1, 2) turned 45 deg left; the laser 0.5 m ahead of it, turned 90
    c = 0.5 * math.cos(math.pi / 4)
    assert poses[1] == pytest.approx((1.0 + c, 2.0 + c, 3 * math.pi / 4))
    assert len(h.out) == 2


def test_the_old_laser_pose_setting_says_what_replaced_it(tmp_path):
    cfg = tmp_path / "legs.yaml"
    cfg.write_text("laser_pose_in_base: [0.5, 0, 0]\n")
    with pytest.raises(SettingsError, match="laser_pose_in_base was replaced by laser_mount"):
        load_settings(LaserLegsSettings, cfg)


def test_the_prediction_is_the_tracker_s_filter_estimate_without_its_lone_leg_shift():
    """TrackState.shift_*: the tracker reports a lone leg's person centre farther out
    (lone_leg_output_m) but associates at its filter's estimate; criterion 3 gates there."""
    p = TargetPredictor()
    t = msgspec.structs.replace(target(0, 2.1, 0.8), shift_x_m=0.1, shift_y_m=-0.05)
    p.add_target(t)
    assert p.predict(two_people(100 * MS)) == pytest.approx((2.0, 0.85))


def test_a_failing_detector_still_answers_the_scan(monkeypatch):
    h = Harness()

    def boom(scan, prediction=None):
        raise RuntimeError("detector bug")

    # the node holds the detector in its handler's closure: break the class under it
    from followbot.services.laser_legs.detectors.thesis import ClusterLegDetector

    monkeypatch.setattr(ClusterLegDetector, "detect", lambda self, s, p=None, _q=None: boom(s, p))
    h.put("sensors/scan", two_people(7 * MS))
    assert [m.stamp_ns for m in h.out] == [7 * MS]
    assert h.out[0].candidates == [] and h.out[0].reach_m == 3.5
    assert h.node.health().errors == 1


def test_bad_detector_settings_fail_at_load_with_the_key():
    with pytest.raises(SettingsError, match=r"unknown field `foo`.*valid keys: clip_range_m"):
        load_settings(LaserLegsSettings, overrides=["detector_settings={foo: 1}"])
    with pytest.raises(SettingsError, match="unknown detector 'nope'; valid names: arc"):
        load_settings(LaserLegsSettings, overrides=["detector=nope"])
    s = load_settings(
        LaserLegsSettings, overrides=["detector=arc", "detector_settings={min_points: 5}"]
    )
    assert s.detector_settings == {"min_points": 5}


# --------------------------------------------------------------------------- real processes


@pytest.mark.multiprocess
@pytest.mark.parametrize("key", ["detector_settings_while_lost", "while_lost_new_near_look_m"])
def test_a_removed_laser_legs_setting_is_named_as_removed(key):
    with pytest.raises(SettingsError, match=f"--set: {key} was removed"):
        load_settings(LaserLegsSettings, overrides=[f"{key}=1"])


def test_synthetic_to_laser_legs_to_a_subscriber(spawn, endpoint, robot, zenoh_session):
    keys = Keys(robot)
    scans: queue.SimpleQueue = queue.SimpleQueue()
    cands: queue.SimpleQueue = queue.SimpleQueue()
    healths: queue.SimpleQueue = queue.SimpleQueue()
    subs = [
        zenoh_session.declare_subscriber(
            keys.topic("sensors/scan"), lambda s: scans.put(s.payload.to_bytes())
        ),
        zenoh_session.declare_subscriber(
            keys.topic("perception/candidates"), lambda s: cands.put(s.payload.to_bytes())
        ),
        zenoh_session.declare_subscriber(
            keys.health("laser_legs"), lambda s: healths.put(decode(Health, s.payload.to_bytes()))
        ),
    ]
    legs = spawn(
        "run", "laser_legs", "--robot", robot, "--connect", endpoint,
        "--set", "health_period_s=0.2",
    )  # fmt: skip
    legs.wait_for_output("laser_legs up", timeout=20)
    healths.get(timeout=10)  # its session is connected: health reaches us
    # bad payloads first: counted as rejected, answered by nothing, the node keeps going
    pub = zenoh_session.declare_publisher(keys.topic("sensors/scan"))
    bad = [b"", b"\xc1" * 50, encode(two_people(1))[:-5]]
    for payload in bad:
        pub.put(payload)
    n = 40
    synthetic = spawn(
        "run", "synthetic", "--robot", robot, "--connect", endpoint,
        "--set", "scan_rate_hz=50", "--set", f"count={n}", "--set", "odom_rate_hz=0",
        "--set", "wait_for_subscribers_s=10",
    )  # fmt: skip
    assert synthetic.wait(60) == 0, synthetic.output
    got: list[PersonCandidates] = []
    deadline = time.monotonic() + 10
    while len(got) < n and time.monotonic() < deadline:
        with contextlib.suppress(queue.Empty):
            got.append(decode(PersonCandidates, cands.get(timeout=0.5)))
    sent = []
    while not scans.empty():
        sent.append(scans.get())
    good_stamps = [m.stamp_ns for m in (_try_scan(p) for p in sent) if m is not None]
    assert len(good_stamps) == n
    # one candidates message per scan, named by the scan's stamp, in order
    assert [m.stamp_ns for m in got] == good_stamps, legs.output
    # the walker circles the robot at 1.5 m: found (two legs or one) in most scans
    near = [
        any(abs(c.range_m - 1.5) < 0.45 for c in m.candidates) and len(m.candidates) <= 2
        for m in got
    ]
    assert sum(near) >= 0.8 * n, [[(c.range_m, c.pattern) for c in m.candidates] for m in got]
    # Health: the bad payloads were rejected, every good scan processed, no handler error
    deadline = time.monotonic() + 5
    h = None
    while time.monotonic() < deadline:
        h = healths.get(timeout=2)
        if h.received.get("sensors/scan", 0) >= n + len(bad):
            break
    assert h is not None
    assert h.rejected["sensors/scan"] == len(bad)
    assert h.received["sensors/scan"] == n + len(bad)
    assert h.errors == 0
    assert "detector=thesis" in h.notes
    legs.signal(signal.SIGTERM)
    assert legs.wait(5) == 0
    for s in subs:
        s.undeclare()


def _try_scan(payload: bytes):
    from followbot.schemas import LaserScan, RejectedMessage

    try:
        return decode(LaserScan, payload)
    except RejectedMessage:
        return None


def test_lockstep_holds_a_scan_until_the_target_of_the_previous_scan_arrives():
    """In lock-step the tracker's answer to scan k races scan k+1; gating k+1 must use it."""
    h = Harness(lockstep_target_wait_s=5.0)
    h.put("sensors/odom", Odometry(stamp_ns=0, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    h.put("sensors/odom", Odometry(stamp_ns=900 * MS, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    h.put("tracking/target", target(0, 1.5, -0.8))  # the tracker is in the loop
    h.put("sensors/scan", two_people(100 * MS))
    assert len(h.out) == 1
    # scan 2 arrives before the tracker's answer to scan 1: held, not gated on a stale target
    h.put("sensors/scan", two_people(200 * MS))
    assert len(h.out) == 1
    h.put("tracking/target", target(100 * MS, 1.5, 0.8))  # the answer to scan 1
    assert len(h.out) == 2
    (c,) = h.out[-1].candidates  # gated on the target of scan 1, not of scan 0
    assert math.hypot(c.x_m - 1.5, c.y_m - 0.8) < 0.1


def test_lockstep_holds_a_scan_until_the_odometry_of_its_instant_arrives():
    """Odometry and scan come on two topics, in no guaranteed order: the prediction for scan k
    must use the odometry of k (interpolated), never an extrapolation from an older one."""

    def run(odometry_first: bool) -> list[PersonCandidates]:
        h = Harness(lockstep_target_wait_s=5.0, lockstep_odometry_wait_s=5.0)
        h.put("sensors/odom", Odometry(stamp_ns=0, x_m=0.0, y_m=0.0, yaw_rad=0.0, v_mps=0.0))
        h.put("tracking/target", target(0, 1.5, 0.5))
        # the robot turned between the two instants; the old twist says it stood still
        odom = Odometry(stamp_ns=100 * MS, x_m=0.0, y_m=0.0, yaw_rad=0.4, w_radps=4.0)
        if odometry_first:
            h.put("sensors/odom", odom)
        h.put("sensors/scan", two_people(100 * MS))
        if not odometry_first:
            assert h.out == []  # held: its odometry is not there yet
            h.put("sensors/odom", odom)
        return h.out

    late, early = run(odometry_first=False), run(odometry_first=True)
    assert len(late) == 1
    assert late == early


def test_the_candidates_carry_the_scans_horizon_unless_switched_off():
    h = Harness()
    h.put("sensors/scan", two_people(5 * MS))
    seen = h.out[-1].horizon
    # 361 beams 0.5 degrees apart: 180.5 degrees in 1-degree bins
    assert seen is not None and seen.ranges.shape == [181]
    r = seen.ranges.numpy()
    # the two people 1.7 m away at +-28 deg hide the wall behind them (3.4 m there)
    for bearing in (28.0, -28.0):
        k = int((math.radians(bearing) - seen.angle_min_rad) / seen.increment_rad)
        assert r[k - 4 : k + 5].min() < 1.8  # (between the legs the wall shows)
    assert r[int(-seen.angle_min_rad / seen.increment_rad)] == pytest.approx(3.0, abs=0.05)
    off = Harness(horizon_bin_deg=None)
    off.put("sensors/scan", two_people(5 * MS))
    assert off.out[-1].horizon is None


def test_the_candidates_carry_the_detector_s_reach():
    """reach_m: the detector's range clip or the scan's maximum range, whichever is nearer;
    through the robot-body filter's wrapper; also on a failing detector's empty answer."""
    cases = [({}, 3.5), ({"detector_settings": {"clip_range_m": None}}, 30.0),
             ({"detector": "iav"}, 30.0), ({"self_filter": None}, 3.5),
             ({"detector_settings": {"clip_range_m": 40.0}}, 30.0)]  # fmt: skip
    for settings, reach in cases:
        h = Harness(**settings)
        h.put("sensors/scan", two_people(7 * MS))  # range_max_m 30
        assert h.out[-1].reach_m == reach, settings


def test_a_failing_horizon_still_sends_the_candidates(monkeypatch, caplog):
    from followbot.services.laser_legs import node as node_module

    def boom(scan, bin_rad):
        raise RuntimeError("horizon bug")

    monkeypatch.setattr(node_module, "horizon", boom)
    h = Harness()
    h.put("sensors/scan", two_people(7 * MS))
    assert [len(m.candidates) for m in h.out] == [2]
    assert h.out[0].horizon is None
    assert "horizon of scan" in caplog.text  # logged (and counted in the Health notes)
