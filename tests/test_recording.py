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


# ----------------------------------------------------------------------------- damaged files


def _readable_scans(path) -> list:
    """The scans readable from ``path`` now (the recorder may still be writing it)."""
    from followbot.mcapio import McapStream

    if not path.exists() or path.stat().st_size == 0:
        return []
    return [m for _, _, m in McapStream(path).messages(["sensors/scan"])]


@pytest.mark.multiprocess
def test_a_recorder_killed_outright_leaves_a_file_that_replays(spawn, endpoint, robot, tmp_path):
    """SIGKILL after ~3 s of messages: the file holds at least the first 2 s, and replays."""
    from followbot.services.runtime.session import free_loopback_endpoint, open_session
    from followbot.services.runtime.settings import ZenohSettings

    out = tmp_path / "killed.mcap"
    rec = spawn("record", "sensors/scan", "sensors/odom", "-o", str(out),
                "--listen", endpoint, "--robot", robot)  # fmt: skip
    rec.wait_for_output("recording", timeout=20)
    syn = spawn("run", "synthetic", "--connect", endpoint, "--robot", robot,
                "--set", "scan_rate_hz=20", "--set", "wait_for_subscribers_s=10")  # fmt: skip
    deadline = time.monotonic() + 30
    while not _readable_scans(out):  # the first flush: messages are coming in
        assert time.monotonic() < deadline, rec.output
        time.sleep(0.05)
    time.sleep(3.0)
    rec.kill()  # SIGKILL: the recorder cannot finish the file
    syn.kill()
    assert rec.p.returncode == -9

    recording = open_recording(out)
    # killed between two flushes (or, rarely, in the middle of writing one)
    reason = recording.damage.reason
    assert "did not finish" in reason or "cut short" in reason, reason
    scans = [m for _, t, m in recording.messages() if t == "sensors/scan"]
    assert (scans[-1].stamp_ns - scans[0].stamp_ns) / 1e9 >= 2.0, len(scans)
    assert [s.seq for s in scans] == list(range(scans[0].seq, scans[0].seq + len(scans)))

    live = free_loopback_endpoint()
    with open_session(ZenohSettings(listen=[live])) as session:
        sub, got = _collect(session, Keys(robot).topic("sensors/scan"))
        run = followbot("replay", str(out), "--connect", live, "--robot", robot,
                        "--rate", "0", "--wait", "10")  # fmt: skip
        time.sleep(0.5)
        replayed = [decode(LaserScan, p) for p in _drain(got)]
        sub.undeclare()
    assert run.returncode == 0, run.stderr
    assert "warning:" in run.stderr and "is damaged" in run.stderr
    assert [s.stamp_ns for s in replayed] == [s.stamp_ns for s in scans]


#: Where a test cuts a finished recording, and what the warning then says.
CUTS = {
    "inside a chunk": (lambda lay: (lay.chunk_ends[2] + lay.chunk_ends[3]) // 2, "cut short"),
    "between two chunks": (lambda lay: lay.chunk_ends[3], "did not finish"),
    "inside the index": (lambda lay: lay.size - 100, "every message was read"),
    "without its last byte": (lambda lay: lay.size - 1, "every message was read"),
}


@pytest.mark.parametrize("where", list(CUTS))
def test_a_cut_recording_is_read_up_to_the_cut(tmp_path, where):
    from recordings import SCAN_PERIOD_NS, T0_NS, write_recording

    layout = write_recording(tmp_path / "whole.mcap")
    offset, words = CUTS[where][0](layout), CUTS[where][1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(layout.path.read_bytes()[:offset])
    rec = open_recording(cut)
    rec.select()
    got = list(rec.messages())
    n = layout.scans_before(offset)
    assert n > 0
    scans = [m.stamp_ns for _, t, m in got if t == "sensors/scan"]
    assert scans == [T0_NS + i * SCAN_PERIOD_NS for i in range(n)]
    assert sum(t == "sensors/odom" for _, t, _ in got) == n
    damage = rec.damage
    assert damage is not None and words in damage.reason
    assert damage.messages == 2 * n  # of the topics replayed: scans and odometry
    assert damage.span_s == pytest.approx((n - 1) * SCAN_PERIOD_NS / 1e9, abs=1e-3)
    assert f"read {2 * n} messages spanning" in damage.describe()


def test_a_damaged_chunk_stops_the_read_there_with_or_without_the_index(tmp_path):
    from recordings import write_recording

    layout = write_recording(tmp_path / "whole.mcap")
    data = bytearray(layout.path.read_bytes())
    middle = (layout.chunk_ends[3] + layout.chunk_ends[4]) // 2
    data[middle : middle + 64] = bytes(64)  # the fifth chunk
    for name, size in (("indexed", len(data)), ("unindexed", layout.chunk_ends[6])):
        bad = tmp_path / f"{name}.mcap"
        bad.write_bytes(data[:size])
        rec = open_recording(bad)
        assert rec.indexed == (name == "indexed")
        scans = [m for _, t, m in rec.messages() if t == "sensors/scan"]
        assert len(scans) == layout.scans_before(layout.chunk_ends[3]), name
        assert rec.damage is not None and rec.damage.messages == 4 * len(scans)  # all topics
        assert "damaged chunk" in rec.damage.reason or "unreadable data" in rec.damage.reason


def test_a_recording_with_nothing_readable_is_a_clear_error(tmp_path):
    from followbot.mcapio import McapTopicWriter

    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"empty file \(0 bytes\)"):
        open_recording(empty)
    started = tmp_path / "started.mcap"
    writer = McapTopicWriter(started, "r")  # killed before its first message: header only
    with pytest.raises(RecordingError, match="no message could be read: the file ends without"):
        open_recording(started)
    writer.close()


@pytest.mark.multiprocess
def test_replay_and_info_read_a_cut_recording_up_to_the_cut(tmp_path, endpoint, robot,
                                                             zenoh_session):  # fmt: skip
    from recordings import write_recording

    layout = write_recording(tmp_path / "whole.mcap")
    offset = (layout.chunk_ends[4] + layout.chunk_ends[5]) // 2
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(layout.path.read_bytes()[:offset])
    n = layout.scans_before(offset)
    info = followbot("replay", str(cut), "--info")
    assert info.returncode == 0, info.stderr
    assert f"read {4 * n} messages" in info.stderr  # all four topics counted on opening

    sub, got = _collect(zenoh_session, Keys(robot).topic("sensors/scan"))
    out = followbot("replay", str(cut), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--wait", "10")  # fmt: skip
    time.sleep(0.5)
    replayed = _drain(got)
    sub.undeclare()
    assert out.returncode == 0, out.stderr
    assert f"replayed {2 * n} messages" in out.stdout
    warning = out.stderr.strip().splitlines()[-1]
    assert warning.startswith(f"warning: {cut} is damaged: read {2 * n} messages spanning")
    assert "cut short" in warning
    assert len(replayed) == n


# ----------------------------------------------------------------------------- which topics


def _collect_topics(session, robot):
    """Every data topic of ``robot`` that arrives, counted."""
    from collections import Counter

    keys, got = Keys(robot), Counter()
    sub = session.declare_subscriber(
        f"{keys.root}/**", lambda s: got.update([keys.topic_of(str(s.key_expr))])
    )
    return sub, got


@pytest.mark.multiprocess
def test_replay_sends_sensor_input_only_unless_told_otherwise(tmp_path, endpoint, robot,
                                                               zenoh_session):  # fmt: skip
    """A recording with sensors, tracks and commands, replayed into a live subscriber: by
    default the recorded commands never reach it (a live pipeline makes its own)."""
    from recordings import write_recording

    n = write_recording(tmp_path / "run.mcap", chunks=2, scans_per_chunk=10).scans_before(10**9)

    def replay(*extra):
        sub, got = _collect_topics(zenoh_session, robot)
        out = followbot("replay", str(tmp_path / "run.mcap"), "--connect", endpoint,
                        "--robot", robot, "--rate", "0", "--wait", "10", *extra)  # fmt: skip
        time.sleep(0.5)
        sub.undeclare()
        assert out.returncode == 0, out.stderr
        return dict(got), out.stderr

    got, log = replay()
    assert got == {"sensors/scan": n, "sensors/odom": n}
    assert "replaying sensors/odom, sensors/scan; skipping control/cmd_vel, tracking/target" in log
    assert "control/cmd_vel" in log and "not sensor input" in log

    got, _ = replay("--all-topics")
    assert got == dict.fromkeys(["sensors/scan", "sensors/odom", "control/cmd_vel",
                                 "tracking/target"], n)  # fmt: skip

    got, log = replay("--topics", "sensors/*,control/*", "--exclude", "sensors/odom")
    assert got == {"sensors/scan": n, "control/cmd_vel": n}
    assert "skipping sensors/odom, tracking/target" in log

    got, _ = replay("--topics", "tracking/target", "--topics", "sensors/sc?n")
    assert got == {"sensors/scan": n, "tracking/target": n}

    typo = followbot("replay", str(tmp_path / "run.mcap"), "--topics", "sensor/*")
    assert typo.returncode == 2
    assert "--topics 'sensor/*' matches no topic" in typo.stderr and "sensors/scan" in typo.stderr
    nothing = followbot("replay", str(tmp_path / "run.mcap"), "--exclude", "sensors/*")
    assert nothing.returncode == 2 and "nothing left to replay" in nothing.stderr
    both = followbot("replay", str(tmp_path / "run.mcap"), "--topics", "x", "--all-topics")
    assert both.returncode == 2 and "not allowed with argument" in both.stderr


def test_replay_help_says_why_the_default_is_sensor_input_only():
    out = followbot("replay", "--help")
    assert out.returncode == 0
    assert "a live pipeline" in out.stdout.replace("\n  ", " ")
    assert "--all-topics" in out.stdout and "--exclude" in out.stdout


# ----------------------------------------------------------------------------- options


def _refused(main, argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize(
    ("command", "option", "value"),
    [
        ("record", "--duration", "-1"),
        ("record", "--duration", "0"),
        ("record", "--duration", "nan"),
        ("replay", "--rate", "-1"),
        ("replay", "--rate", "inf"),
        ("replay", "--wait", "-0.5"),
        ("replay", "--timeout", "0"),
        ("track", "--max-scans", "0"),
        ("track", "--max-scans", "-3"),
        ("track", "--max-scans", "2.5"),
        ("track", "--timeout", "-1"),
        ("run synthetic", "--duration", "-1"),
        ("run synthetic", "--duration", "nan"),
        ("run laser_legs+tracker", "--duration", "0"),
        ("smoke", "--duration", "0"),
        ("smoke", "--scan-rate", "-40"),
        ("smoke", "--image-rate", "-1"),
        ("sweep", "--jobs", "0"),
        ("target", "--wait", "-1"),
        ("target", "--timeout", "nan"),
    ],
)
def test_non_positive_or_non_finite_durations_counts_and_rates_are_refused(
    command, option, value, capsys, tmp_path
):
    from followbot.cli import main

    required = {
        "replay": ["x.mcap"],
        "track": ["x.mcap", "--scan-topic", "s", "--output", str(tmp_path)],
        "sweep": ["--output", str(tmp_path)],
        "target": ["reset"],
    }
    argv = [*command.split(), *required.get(command, []), f"{option}={value}"]
    err = _refused(main, argv, capsys)
    assert f"argument {option}: must be a " in err and f"got {value!r}" in err


# ----------------------------------------------------------------------------- ROS 1 bags


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_a_cut_ros1_bag_is_read_up_to_the_cut(tmp_path, compression):
    """rosbags needs the index at the end of a bag: a cut one is read front to back instead."""
    from recordings import write_ros1_bag

    whole = tmp_path / "whole.bag"
    stamps = write_ros1_bag(whole, compression=compression, chunk_bytes=20_000)
    data = whole.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    rec = open_recording(cut)
    assert not rec.indexed and rec.mapping == {"/scan": "sensors/scan"}
    scans = [m for _, _, m in rec.messages()]
    assert 0 < len(scans) < len(stamps)
    assert [s.stamp_ns for s in scans] == stamps[: len(scans)]
    np.testing.assert_array_equal(scans[-1].ranges_m(), next(
        m for _, _, m in open_recording(whole).messages() if m.stamp_ns == scans[-1].stamp_ns
    ).ranges_m())  # fmt: skip
    assert rec.damage is not None and "cut short" in rec.damage.reason
    assert rec.damage.messages == len(scans) and rec.skipped == {}


def test_an_uncompressed_ros1_chunk_cut_short_gives_its_messages_up_to_the_cut(tmp_path):
    from recordings import write_ros1_bag

    whole = tmp_path / "whole.bag"
    stamps = write_ros1_bag(whole, chunk_bytes=1 << 30)  # one chunk, written at the close
    data = whole.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])  # inside the only chunk
    rec = open_recording(cut)
    got = [m.stamp_ns for _, _, m in rec.messages()]
    assert len(stamps) // 3 < len(got) < len(stamps) and got == stamps[: len(got)]
    assert "ends inside an uncompressed chunk" in rec.damage.reason


def test_an_unfinished_ros1_bag_is_read_whole(tmp_path):
    """`rosbag record` killed leaves a .bag.active: its chunks written, no index."""
    import struct

    from recordings import write_ros1_bag

    whole = tmp_path / "whole.bag"
    stamps = write_ros1_bag(whole, compression="lz4", chunk_bytes=20_000)
    data = bytearray(whole.read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    (index_pos,) = struct.unpack_from("<Q", data, at)
    data[at : at + 8] = bytes(8)  # never indexed, as the recorder leaves it
    active = tmp_path / "run.bag.active"
    active.write_bytes(data[:index_pos])
    rec = open_recording(active)
    assert [m.stamp_ns for _, _, m in rec.messages()] == stamps
    assert "never indexed" in rec.damage.reason and rec.damage.messages == len(stamps)
    info = followbot("replay", str(active), "--info")
    assert info.returncode == 0, info.stderr
    assert "/scan" in info.stderr and "-> sensors/scan" in info.stderr
    assert f"is damaged: read {len(stamps)} messages" in info.stderr


def test_a_bag_with_nothing_readable_is_a_clear_error(tmp_path):
    from recordings import write_ros1_bag

    whole = tmp_path / "whole.bag"
    write_ros1_bag(whole)
    stub = tmp_path / "stub.bag"
    stub.write_bytes(whole.read_bytes()[:5000])  # the bag header, not one message
    with pytest.raises(RecordingError, match="no message could be read"):
        open_recording(stub)
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    out = followbot("replay", str(junk))
    assert out.returncode == 2 and "not a ROS 1 bag" in out.stderr
