"""Record to MCAP and replay MCAP / ROS bags, with real processes over Zenoh."""

from __future__ import annotations

import itertools
import math
import queue
import subprocess
import sys
import time
from types import SimpleNamespace as NS

import numpy as np
import pytest
from conftest import SHARED_DATA

from followbot.bags import RecordingError, convert, open_recording
from followbot.schemas import Keys, LaserScan, decode

DEMO_BAG = SHARED_DATA / "leg_tracker" / "demo_stationary_simple_environment.bag"
NEGATIVE_BAG = SHARED_DATA / "leg_tracker" / "negative_2.bag"
needs_data = pytest.mark.skipif(
    not DEMO_BAG.is_file(), reason=f"leg_tracker recordings absent at {DEMO_BAG.parent}"
)


def followbot(*args, timeout=60):
    return subprocess.run(
        [sys.executable, "-m", "followbot", *args], capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def _collect(session, key):
    got: queue.SimpleQueue = queue.SimpleQueue()
    sub = session.declare_subscriber(key, lambda s: got.put(s.payload.to_bytes()))
    return sub, got


def _drain(q: queue.SimpleQueue) -> list[bytes]:
    out = []
    while not q.empty():
        out.append(q.get())
    return out


@pytest.fixture
def recorded(spawn, endpoint, robot, tmp_path):
    """An MCAP of 100 synthetic scans (and odometry), recorded over Zenoh."""
    out = tmp_path / "rec.mcap"
    rec = spawn("record", "sensors/scan", "sensors/odom", "-o", str(out),
                "--listen", endpoint, "--robot", robot)  # fmt: skip
    time.sleep(1.0)
    syn = spawn(
        "run", "synthetic", "--connect", endpoint, "--robot", robot,
        "--set", "scan_rate_hz=100", "--set", "count=100", "--set", "wait_for_subscribers_s=10",
    )  # fmt: skip
    assert syn.wait(30) == 0, syn.output
    time.sleep(0.5)
    rec.signal(2)
    assert rec.wait(10) == 0, rec.output
    assert "wrote" in rec.output and "sensors/scan" in rec.output
    return out


@pytest.mark.multiprocess
def test_record_writes_a_valid_indexed_mcap(recorded):
    from mcap.reader import make_reader

    with recorded.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "file not finished (no summary section)"
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["followbot"]["schema_version"] == "1"
        scans = [
            decode(LaserScan, m.data) for _, ch, m in reader.iter_messages(topics=["sensors/scan"])
        ]
    assert len(scans) == 100
    assert [s.seq for s in scans] == list(range(100))
    channels = {c.topic: c for c in summary.channels.values()}
    assert channels["sensors/scan"].message_encoding == "msgpack"
    assert summary.schemas[channels["sensors/scan"].schema_id].encoding == "jsonschema"


@pytest.mark.multiprocess
def test_replay_round_trips_the_recorded_messages(recorded, endpoint, robot, zenoh_session):
    sub, got = _collect(zenoh_session, Keys(robot).topic("sensors/scan"))
    out = followbot("replay", str(recorded), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--wait", "10")  # fmt: skip
    assert out.returncode == 0, out.stderr
    time.sleep(0.5)
    replayed = [decode(LaserScan, p) for p in _drain(got)]
    sub.undeclare()
    original = [m for _, t, m in open_recording(recorded).messages() if t == "sensors/scan"]
    assert len(replayed) == len(original) == 100
    for a, b in zip(replayed, original, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.ranges_m(), b.ranges_m())


@pytest.mark.multiprocess
def test_truncated_mcap_gives_a_clear_error_not_a_hang(recorded, tmp_path, endpoint, robot):
    cut = tmp_path / "cut.mcap"
    data = recorded.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    out = followbot("replay", str(cut), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--wait", "0", timeout=30)  # fmt: skip
    assert out.returncode in (1, 2)
    assert "truncated" in (out.stderr + out.stdout)


@needs_data
@pytest.mark.multiprocess
def test_a_ros1_bag_replays_as_followbot_scans(endpoint, robot, zenoh_session):
    sub, got = _collect(zenoh_session, Keys(robot).topic("sensors/scan"))
    out = followbot("replay", str(DEMO_BAG), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--wait", "10", timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    time.sleep(0.5)
    scans = [decode(LaserScan, p) for p in _drain(got)]
    sub.undeclare()
    assert len(scans) == 1265
    _, topic, first = next(open_recording(DEMO_BAG).messages())
    assert topic == "sensors/scan"
    np.testing.assert_array_equal(scans[0].ranges_m(), first.ranges_m())
    assert scans[0].stamp_ns == first.stamp_ns and scans[0].frame_id == first.frame_id
    assert all(b.stamp_ns >= a.stamp_ns for a, b in itertools.pairwise(scans))


@needs_data
def test_ambiguous_bag_topics_ask_for_a_remap():
    with pytest.raises(RecordingError, match="--remap SRC=sensors/scan"):
        open_recording(NEGATIVE_BAG)
    rec = open_recording(NEGATIVE_BAG, {"/rear_scan": "sensors/scan"})
    assert rec.mapping == {"/rear_scan": "sensors/scan"}
    with pytest.raises(RecordingError, match="no topic"):
        open_recording(NEGATIVE_BAG, {"/nope": "sensors/scan"})


def test_files_that_are_not_recordings_are_refused(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"definitely not mcap")
    with pytest.raises(RecordingError, match="not a readable MCAP"):
        open_recording(junk)
    with pytest.raises(RecordingError, match="not a recording followbot reads"):
        open_recording(tmp_path / "x.txt" if (tmp_path / "x.txt").write_text("x") else None)
    with pytest.raises(RecordingError, match="no such file"):
        open_recording(tmp_path / "missing.bag")
    out = followbot("replay", str(junk))
    assert out.returncode == 2 and "not a readable MCAP" in out.stderr


def _header(sec=0, nanosec=0, frame="f"):
    return NS(stamp=NS(sec=sec, nanosec=nanosec), frame_id=frame)


def test_ros_odometry_yaw_comes_from_the_quaternion():
    yaw = 0.7
    ros = NS(
        header=_header(5, 10),
        child_frame_id="base_link",
        pose=NS(pose=NS(position=NS(x=1.0, y=2.0, z=0.0),
                        orientation=NS(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))),
        twist=NS(twist=NS(linear=NS(x=0.3), angular=NS(z=-0.1))),
    )  # fmt: skip
    odom = convert("nav_msgs/msg/Odometry", ros, t_ns=99)
    assert odom.yaw_rad == pytest.approx(yaw) and odom.stamp_ns == 5_000_000_010
    assert (odom.x_m, odom.v_mps, odom.w_radps) == (1.0, 0.3, -0.1)


def test_ros_rgb_image_with_row_padding_becomes_bgr():
    h, w, step = 2, 3, 12  # 9 bytes of pixels + 3 of padding per row
    rows = np.zeros((h, step), np.uint8)
    rows[:, 0:9] = np.tile([10, 20, 30], w)  # r, g, b
    ros = NS(header=_header(), height=h, width=w, step=step, encoding="rgb8",
             data=rows.ravel())  # fmt: skip
    img = convert("sensor_msgs/msg/Image", ros, t_ns=7)
    assert img.stamp_ns == 7  # a zero header stamp falls back to the bag time
    assert img.pixels().shape == (2, 3, 3)
    assert tuple(img.pixels()[1, 2]) == (30, 20, 10)


def test_ros_scan_converts_with_its_geometry():
    ros = NS(header=_header(1, 0, "laser"), angle_min=-1.0, angle_max=1.0, angle_increment=0.5,
             time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=10.0,
             ranges=[1.0, 2.0, float("inf"), 3.0, 4.0], intensities=[])  # fmt: skip
    scan = convert("sensor_msgs/msg/LaserScan", ros, t_ns=0)
    assert scan.frame_id == "laser" and scan.intensities is None
    np.testing.assert_allclose(scan.angles_rad(), [-1.0, -0.5, 0.0, 0.5, 1.0])


@needs_data
@pytest.mark.multiprocess
def test_lockstep_replay_waits_for_every_scan_to_be_answered(spawn, endpoint, robot, zenoh_session):
    from followbot.schemas import PersonCandidates

    sub, got = _collect(zenoh_session, Keys(robot).topic("perception/candidates"))
    legs = spawn("run", "laser_legs", "--connect", endpoint, "--robot", robot)
    legs.wait_for_output("laser_legs up", timeout=20)
    out = followbot("replay", str(DEMO_BAG), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--lockstep", timeout=180)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "lock-step with: laser_legs" in out.stderr
    assert "did not answer" not in out.stdout
    time.sleep(0.3)
    answers = [decode(PersonCandidates, p) for p in _drain(got)]
    sub.undeclare()
    scans = [m for _, t, m in open_recording(DEMO_BAG).messages() if t == "sensors/scan"]
    assert [a.stamp_ns for a in answers] == [s.stamp_ns for s in scans]  # one each, in order
