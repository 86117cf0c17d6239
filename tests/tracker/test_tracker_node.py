"""Tracker and controller nodes on the in-process fake bus: one answer per stamp, watchdog."""

from __future__ import annotations

import json
import math
import time

import msgspec
import numpy as np
import pytest

from followbot.schemas import (
    Array,
    Candidate,
    Keys,
    LaserScan,
    Odometry,
    PanCommand,
    People,
    PersonCandidates,
    TargetModel,
    TrackState,
    VelocityCommand,
    Verification,
    VerifiedCandidate,
    decode,
    encode,
)
from followbot.services.controller.node import ControllerNodeSettings
from followbot.services.controller.node import setup as controller_setup
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import NodeSettings, SettingsError, load_settings
from followbot.services.tracker.node import TrackerNodeSettings
from followbot.services.tracker.node import setup as tracker_setup

KEYS = Keys("robot")
SCAN_NS = 120_000_000


def of(net, topic, kind):
    key = KEYS.topic(topic)
    return [decode(kind, p) for k, p in net.published if k == key]


def candidates(stamp_ns, x, y):
    c = Candidate(x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x))
    return PersonCandidates(stamp_ns=stamp_ns, frame_id="base_laser", candidates=[c])


def room_scan(stamp_ns, wall_ahead_m=6.0):
    """A 180 deg scan of a room 6 m round (the controller's obstacle guard reads it), with a
    wall ``wall_ahead_m`` ahead across the middle 60 deg."""
    r = np.full(181, 6.0, dtype=np.float32)
    r[60:121] = wall_ahead_m / np.cos(np.radians(np.arange(-30, 31)))
    return LaserScan(
        stamp_ns=stamp_ns,
        frame_id="base_laser",
        angle_min_rad=-math.pi / 2,
        angle_increment_rad=math.pi / 180,
        range_min_m=0.05,
        range_max_m=30.0,
        ranges=Array.from_numpy(r),
    )


@pytest.fixture
def pipeline():
    net = FakeNetwork()
    tsettings = load_settings(TrackerNodeSettings, overrides=["acquire=nearest"])
    tracker = Node("tracker", tsettings, net.bus("tracker"))
    tracker_setup(tracker, tsettings)
    tracker.announce()  # what run() does once set up
    csettings = load_settings(ControllerNodeSettings, overrides=["watchdog_period_s=0.02"])
    controller = Node("controller", csettings, net.bus("controller"))
    controller_setup(controller, csettings)
    controller.announce()
    yield net, tracker, controller
    controller.close()


def test_one_target_people_and_command_per_candidates_message_naming_its_stamp(pipeline):
    net, tracker, _ = pipeline
    stamps = [k * SCAN_NS for k in range(1, 11)]
    for k, stamp in enumerate(stamps):
        net.put(
            KEYS.topic("sensors/odom"), encode(Odometry(stamp_ns=stamp, x_m=0, y_m=0, yaw_rad=0))
        )
        net.put(KEYS.topic("sensors/scan"), encode(room_scan(stamp)))
        net.put(KEYS.topic("perception/candidates"), encode(candidates(stamp, 2.5, 0.02 * k)))
    targets = of(net, "tracking/target", TrackState)
    assert [t.stamp_ns for t in targets] == stamps
    assert [p.stamp_ns for p in of(net, "tracking/people", People)] == stamps
    cmds = of(net, "control/cmd_vel", VelocityCommand)
    assert [c.stamp_ns for c in cmds] == stamps
    assert [p.stamp_ns for p in of(net, "control/pan", PanCommand)] == stamps
    assert targets[-1].status == "tracking" and targets[-1].estimator == "particle"
    assert "no_vision" in targets[-1].flags
    assert cmds[-1].linear_mps > 0 and cmds[-1].reason == "max_speed"
    assert tracker.health().errors == 0


def test_controller_brakes_to_zero_when_the_tracker_goes_away(pipeline):
    net, tracker, controller = pipeline
    for k in range(1, 30):
        stamp = k * SCAN_NS
        net.put(
            KEYS.topic("sensors/odom"), encode(Odometry(stamp_ns=stamp, x_m=0, y_m=0, yaw_rad=0))
        )
        net.put(KEYS.topic("sensors/scan"), encode(room_scan(stamp)))
        net.put(KEYS.topic("perception/candidates"), encode(candidates(stamp, 3.0, 0.0)))
    moving = of(net, "control/cmd_vel", VelocityCommand)[-1]
    assert moving.linear_mps > 0.5
    tracker.close()  # its liveliness token goes
    deadline = time.monotonic() + 5.0
    cmds = []
    while time.monotonic() < deadline:
        controller.spin_once()
        cmds = [
            c for c in of(net, "control/cmd_vel", VelocityCommand) if c.reason == "tracker_gone"
        ]
        if cmds and cmds[-1].linear_mps == 0.0 and cmds[-1].angular_radps == 0.0:
            break
        time.sleep(0.01)
    assert cmds, "no watchdog command after the tracker left"
    assert cmds[-1].linear_mps == 0.0 and cmds[-1].angular_radps == 0.0
    speeds = [c.linear_mps for c in cmds]
    assert speeds == sorted(speeds, reverse=True)  # a ramp down, never up
    n = len(of(net, "control/cmd_vel", VelocityCommand))
    for _ in range(5):
        controller.spin_once()
        time.sleep(0.02)
    assert len(of(net, "control/cmd_vel", VelocityCommand)) == n  # at rest: it stops talking


def test_the_controller_stops_without_a_scan_and_short_of_a_wall(pipeline):
    """guard.enabled (default): no sensors/scan -> each target is answered after
    scan_wait_s, and the base stays put (no_scan); a wall 0.6 m ahead between the robot and a
    target 3 m away -> it does not drive into it."""
    net, _, controller = pipeline

    def step(k, scan):
        stamp = k * SCAN_NS
        net.put(
            KEYS.topic("sensors/odom"), encode(Odometry(stamp_ns=stamp, x_m=0, y_m=0, yaw_rad=0))
        )
        if scan is not None:
            net.put(KEYS.topic("sensors/scan"), encode(scan(stamp)))
        net.put(KEYS.topic("perception/candidates"), encode(candidates(stamp, 3.0, 0.0)))
        if scan is None:  # the target waits for its scan; the watchdog gives up on it
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline and not [
                c for c in of(net, "control/cmd_vel", VelocityCommand) if c.stamp_ns == stamp
            ]:
                controller.spin_once()
                time.sleep(0.01)
        (c,) = [c for c in of(net, "control/cmd_vel", VelocityCommand) if c.stamp_ns == stamp]
        return c

    assert {step(k, None).reason for k in range(1, 8)} >= {"no_scan"}
    assert step(8, None).linear_mps == 0.0
    assert controller.health().notes == ["targets_without_their_scan=8"]
    last = [step(k, lambda t: room_scan(t, wall_ahead_m=0.6)) for k in range(9, 40)]
    assert all(c.linear_mps < 0.3 for c in last)  # never near full speed at the wall
    assert last[-1].reason.startswith("avoid_")


def test_a_target_that_overtakes_its_scan_waits_for_it(pipeline):
    """The tracker's answer can reach the controller before the laser's own scan of that
    stamp: the command then waits for the scan and uses it (a wall 0.4 m ahead: no speed)."""
    net, _, _ = pipeline
    for k in range(1, 12):
        stamp = k * SCAN_NS
        net.put(
            KEYS.topic("sensors/odom"), encode(Odometry(stamp_ns=stamp, x_m=0, y_m=0, yaw_rad=0))
        )
        wall = 0.4 if k == 11 else 6.0
        if k < 11:
            net.put(KEYS.topic("sensors/scan"), encode(room_scan(stamp, wall_ahead_m=wall)))
        net.put(KEYS.topic("perception/candidates"), encode(candidates(stamp, 3.0, 0.0)))
    cmds = of(net, "control/cmd_vel", VelocityCommand)
    assert [c.stamp_ns for c in cmds] == [k * SCAN_NS for k in range(1, 11)]  # 11 waits
    net.put(KEYS.topic("sensors/scan"), encode(room_scan(11 * SCAN_NS, wall_ahead_m=0.4)))
    last = of(net, "control/cmd_vel", VelocityCommand)[-1]
    assert last.stamp_ns == 11 * SCAN_NS and last.reason.startswith("avoid_")


def test_bad_estimator_setting_is_a_settings_error():
    # while the settings load, before any node or network exists
    with pytest.raises(SettingsError, match="unknown estimator 'nope'; valid names"):
        load_settings(TrackerNodeSettings, overrides=["estimator=nope"])


def test_every_retired_tracker_setting_is_refused_with_its_own_message():
    """Each key the tracker lists as retired is no setting any more, and naming it fails
    with the table's message rather than an unknown-field error."""
    retired = TrackerNodeSettings.retired_settings
    assert retired and not set(retired) & set(TrackerNodeSettings.__struct_fields__)
    defaults = msgspec.to_builtins(TrackerNodeSettings())
    for key, note in retired.items():
        with pytest.raises(SettingsError) as err:
            load_settings(TrackerNodeSettings, None, [f"{key}=1"])
        assert str(err.value) == f"--set: {key} {note}"
        if "renamed" in note:  # the new key exists and takes a value
            new = note.split("set ")[1].split()[0]
            section, name = new.split(".")
            value = defaults[section][name]
            loaded = load_settings(TrackerNodeSettings, None, [f"{new}={json.dumps(value)}"])
            assert msgspec.to_builtins(getattr(loaded, section))[name] == value


def test_a_nested_setting_is_set_by_its_dotted_key_or_a_section_in_a_file(tmp_path):
    cfg = tmp_path / "tracker.yaml"
    cfg.write_text("search: {gate_m: 0.8}\nidentity: {switch_votes: 3}\n")
    s = load_settings(TrackerNodeSettings, cfg, ["search.dwell_s=2"])
    assert (s.search.gate_m, s.search.dwell_s, s.identity.switch_votes) == (0.8, 2.0, 3)
    assert s.search.max_s == 4.0  # the section's other defaults stay
    with pytest.raises(SettingsError, match=r"look_gate_m was renamed: set search\.gate_m instead"):
        load_settings(TrackerNodeSettings, None, ["look_gate_m=0.8"])


def test_the_tracker_keeps_the_target_model_for_a_restarted_vision_worker(pipeline):
    net, tracker, _ = pipeline
    model = TargetModel(
        stamp_ns=5, model_id=3, verifier="histogram", x_m=1.5, y_m=0.0, rect_width_px=60,
        rect_height_px=180, image_width=320, image_height=240,
    )  # fmt: skip
    vision = Node("vision_verify", load_settings(NodeSettings), net.bus("vision"))
    assert vision.query("perception/target_model") == []
    net.put(KEYS.topic("perception/target_model"), encode(model))
    tracker.spin_once()
    (answer,) = vision.query("perception/target_model")  # the worker that built it is gone
    assert answer.model_id == 3 and answer.x_m == 1.5


def _tracker_outputs(messages, *settings):
    """Feed ``(topic, message)`` in this order to a tracker node; its tracking/target."""
    net = FakeNetwork()
    s = load_settings(TrackerNodeSettings, overrides=list(settings))
    node = Node("tracker", s, net.bus("tracker"))
    tracker_setup(node, s)
    for topic, message in messages:
        net.put(KEYS.topic(topic), encode(message))
        node.spin_once()
    return of(net, "tracking/target", TrackState)


def test_lockstep_a_step_waits_for_the_odometry_of_its_scan():
    """Odometry comes from the source, candidates through laser_legs: either may come first.
    Both orders give the same step (interpolated, not extrapolated from an older pose)."""
    still = Odometry(stamp_ns=0, x_m=0.0, y_m=0.0, yaw_rad=0.0)
    turned = Odometry(stamp_ns=SCAN_NS, x_m=0.05, y_m=0.0, yaw_rad=0.3, w_radps=2.5)
    c0, c1 = candidates(0, 2.0, 0.0), candidates(SCAN_NS, 1.9, -0.6)
    odometry_first = [("sensors/odom", still), ("perception/candidates", c0),
                      ("sensors/odom", turned), ("perception/candidates", c1)]  # fmt: skip
    candidates_first = [("sensors/odom", still), ("perception/candidates", c0),
                        ("perception/candidates", c1), ("sensors/odom", turned)]  # fmt: skip
    wait = ["acquire=nearest", "lockstep_odometry_wait_s=5"]
    a = _tracker_outputs(odometry_first, *wait)
    b = _tracker_outputs(candidates_first, *wait)
    assert [t.stamp_ns for t in a] == [0, SCAN_NS]
    assert a == b
    # what the wait prevents: without it the second order steps before the turn is known
    assert _tracker_outputs(candidates_first, "acquire=nearest")[-1] != a[-1]


def test_lockstep_vision_is_applied_at_the_same_step_whatever_the_arrival_order():
    """A verification (and the model it was judged with) reaches the tracker by another link
    than the candidates; in lock-step it takes effect at a fixed step all the same."""
    model = TargetModel(
        stamp_ns=0, model_id=1, verifier="histogram", x_m=2.0, y_m=-0.5, rect_width_px=60,
        rect_height_px=180, image_width=320, image_height=240,
    )  # fmt: skip
    two = [Candidate(x_m=2.0, y_m=y, range_m=2.0, bearing_rad=0.0) for y in (-0.5, 0.5)]
    verification = Verification(
        stamp_ns=0, image_stamp_ns=0, model_id=1, verifier="histogram", chosen=1,
        candidates=[VerifiedCandidate(index=i, x_m=c.x_m, y_m=c.y_m, in_view=True, distance=0.1)
                    for i, c in enumerate(two)],
    )  # fmt: skip
    scans = [PersonCandidates(stamp_ns=k * SCAN_NS, candidates=two) for k in range(4)]
    odom = [Odometry(stamp_ns=k * SCAN_NS, x_m=0.0, y_m=0.0, yaw_rad=0.0) for k in range(4)]

    m, v = ("perception/target_model", model), ("perception/verification", verification)
    c1 = [("sensors/odom", odom[1]), ("perception/candidates", scans[1])]
    orders = [[m, v, *c1], [v, *c1, m], [*c1, m, v]]

    def run(order, *settings):
        msgs = [("sensors/odom", odom[0]), ("perception/candidates", scans[0]), *order]
        for k in (2, 3):  # vision answers every scan in lock-step (here: no choice)
            empty = Verification(stamp_ns=(k - 1) * SCAN_NS, image_stamp_ns=0, model_id=1,
                                 verifier="histogram")  # fmt: skip
            msgs += [("perception/verification", empty), ("sensors/odom", odom[k]),
                     ("perception/candidates", scans[k])]  # fmt: skip
        return _tracker_outputs(msgs, *settings)

    wait = ["lockstep_odometry_wait_s=5", "lockstep_vision_wait_s=5"]
    results = [run(o, *wait) for o in orders]
    assert all(len(r) == 4 for r in results)
    assert [t.status for t in results[0]] == ["initialising", "tracking", "tracking", "tracking"]
    assert results[1] == results[0] and results[2] == results[0]
    # without the waits, the last order takes the target one scan later
    assert run(orders[2])[1] != results[0][1]
