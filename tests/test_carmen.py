"""CARMEN logs: records to followbot messages, beam geometry measured on real logs, malformed
lines counted, unusable clocks restamped, and replay/track on them end to end."""

from __future__ import annotations

import csv
import gzip
import math
import queue
import subprocess
import sys
import time

import numpy as np
import pytest
from carmen_logs import candidates, flaser_scans, residual_m
from conftest import SHARED_DATA
from hypothesis import given, settings
from hypothesis import strategies as st

from followbot.bags import RecordingError, open_recording
from followbot.carmen import CarmenLog, flaser_geometry
from followbot.schemas import Keys, LaserScan, Odometry, decode

CARMEN = SHARED_DATA / "carmen"
needs_data = pytest.mark.skipif(
    not (CARMEN / "aces-corrected.log.gz").is_file(), reason=f"CARMEN logs absent at {CARMEN}"
)
T0 = "1134863807.658747"  # an absolute CARMEN timestamp (s, microseconds)
T0_NS = 1_134_863_807_658_747_000


def stamp(dt_s: float) -> str:
    """``T0 + dt_s`` as CARMEN writes it (6 decimals)."""
    return f"{1134863807.658747 + dt_s:.6f}"


def ns(dt_s: float) -> int:
    return T0_NS + round(dt_s * 1e6) * 1000


def flaser(ranges, t: str, pose=(1.0, 2.0, 0.5), odom=(0.1, 0.2, 0.3), name="FLASER") -> str:
    r = " ".join(f"{v:g}" for v in ranges)
    p = " ".join(map(str, (*pose, *odom)))
    return f"{name} {len(ranges)} {r} {p} {t} host {t}"


def odom(x, y, theta, tv, rv, t: str) -> str:
    return f"ODOM {x} {y} {theta} {tv} {rv} 0 {t} host {t}"


def robotlaser(ranges, remissions, t: str, start=-2.0, res=0.02, max_range=30.0,
               laser=(5.0, 6.0, 0.7), robot=(4.9, 6.1, 0.6), tv=0.4, rv=-0.1) -> str:  # fmt: skip
    cfg = f"0 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0"
    r = " ".join(f"{v:g}" for v in ranges)
    e = " ".join(f"{v:g}" for v in remissions)
    poses = " ".join(map(str, (*laser, *robot, tv, rv, 0.5, 0.3, 0.0)))
    return f"ROBOTLASER1 {cfg} {len(ranges)} {r} {len(remissions)} {e} {poses} {t} host {t}"


def rawlaser(ranges, t: str, start=-1.5, res=0.05, max_range=8.0, name="RAWLASER1") -> str:
    cfg = f"1 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0"
    r = " ".join(f"{v:g}" for v in ranges)
    return f"{name} {cfg} {len(ranges)} {r} 0 {t} host {t}"


def write(path, lines, gz=False):
    text = "".join(line + "\n" for line in lines)
    if gz:
        path.write_bytes(gzip.compress(text.encode()))
    else:
        path.write_text(text)
    return path


def followbot(*args, timeout=60):
    return subprocess.run(
        [sys.executable, "-m", "followbot", *args], capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


# ----------------------------------------------------------------------------- records


def test_laser_and_odometry_records_become_followbot_messages_in_stamp_order(tmp_path):
    ranges = np.round(np.linspace(0.5, 9.0, 180), 2)
    ranges[7] = 81.91  # no return
    robot_ranges, remissions = [1.0, 2.0, 30.0, 45.0, 3.0], [10.0, 20.0, 30.0, 40.0, 50.0]
    path = write(tmp_path / "run.log", [
        "# CARMEN Logfile",
        "PARAM robot_frontlaser_offset 0.0 host 0",
        odom(0.0, 0.0, 0.0, 0.0, 0.0, T0),
        flaser(ranges, stamp(0.2)),
        odom(0.5, 0.25, 7.0, 0.3, 0.05, stamp(0.1)),  # written late: stamped before the scan
        robotlaser(robot_ranges, remissions, stamp(0.3)),
        rawlaser([1.0, 8.0, 9.5], stamp(0.4)),
        odom(0.6, 0.3, 0.1, 0.3, 0.0, stamp(0.5)),
    ])  # fmt: skip
    log = CarmenLog(path)
    assert log.contents == {
        "ODOM": ("Odometry", 3), "FLASER": ("LaserScan", 1), "FLASER/odom": ("Odometry", 1),
        "ROBOTLASER1": ("LaserScan", 1), "ROBOTLASER1/odom": ("Odometry", 1),
        "RAWLASER1": ("LaserScan", 1),
    }  # fmt: skip
    got = list(log.messages(list(log.contents)))
    assert [(t, src) for t, src, _ in got] == [
        (T0_NS, "ODOM"), (ns(0.1), "ODOM"), (ns(0.2), "FLASER/odom"), (ns(0.2), "FLASER"),
        (ns(0.3), "ROBOTLASER1/odom"), (ns(0.3), "ROBOTLASER1"), (ns(0.4), "RAWLASER1"),
        (ns(0.5), "ODOM"),
    ]  # fmt: skip
    assert all(m.stamp_ns == t for t, _, m in got)
    m = {src: msg for _, src, msg in got}

    scan = m["FLASER"]
    assert isinstance(scan, LaserScan) and scan.frame_id == "front_laser"
    assert scan.angle_min_rad == -math.pi / 2 and scan.angle_increment_rad == math.pi / 180
    assert scan.range_max_m == 80.0
    expected = ranges.astype(np.float32)
    expected[7] = np.inf
    np.testing.assert_array_equal(scan.ranges_m(), expected)
    # the odometry fields, not the corrected pose x y theta
    fo = m["FLASER/odom"]
    assert (fo.x_m, fo.y_m, fo.yaw_rad, fo.frame_id) == (0.1, 0.2, 0.3, "odom")

    robot = m["ROBOTLASER1"]
    assert robot.angle_min_rad == -2.0 and robot.angle_increment_rad == 0.02
    assert robot.range_max_m == 30.0 and robot.frame_id == "laser1"
    np.testing.assert_array_equal(robot.ranges_m(), [1.0, 2.0, np.inf, np.inf, 3.0])
    np.testing.assert_array_equal(robot.intensities.numpy(), remissions)
    ro = m["ROBOTLASER1/odom"]
    assert (ro.x_m, ro.y_m, ro.yaw_rad, ro.v_mps, ro.w_radps) == (4.9, 6.1, 0.6, 0.4, -0.1)

    raw = m["RAWLASER1"]
    np.testing.assert_array_equal(raw.ranges_m(), [1.0, np.inf, np.inf])
    assert raw.angle_min_rad == -1.5 and raw.intensities is None

    late = [msg for _, src, msg in got if src == "ODOM"][1]
    assert isinstance(late, Odometry)
    assert (late.x_m, late.v_mps, late.w_radps) == (0.5, 0.3, 0.05)
    assert late.yaw_rad == pytest.approx(7.0 - 2 * math.pi)  # within +-pi


@pytest.mark.parametrize(("beams", "last_deg"), [(180, 89.0), (181, 90.0), (360, 89.5),
                                                 (361, 90.0)])  # fmt: skip
def test_flaser_beams_cover_180_degrees_from_the_right(tmp_path, beams, last_deg):
    start, step = flaser_geometry(beams)
    assert math.degrees(start) == pytest.approx(-90.0)
    assert math.degrees(start + step * (beams - 1)) == pytest.approx(last_deg)
    path = write(tmp_path / "g.log", [flaser(np.full(beams, 2.0), T0)])
    [scan] = [m for _, topic, m in open_recording(path).messages() if topic == "sensors/scan"]
    np.testing.assert_allclose(np.degrees(scan.angles_rad()[[0, -1]]), [-90.0, last_deg])


def test_the_default_sources_are_the_front_laser_and_its_odometry(tmp_path):
    lines = [odom(0, 0, 0, 0, 0, T0), flaser([1.0] * 181, stamp(1), name="RLASER"),
             flaser([1.0] * 181, stamp(1)), robotlaser([1.0] * 3, [], stamp(2))]  # fmt: skip
    rec = open_recording(write(tmp_path / "a.log", lines))
    assert rec.kind == "carmen"
    assert rec.mapping == {"ROBOTLASER1": "sensors/scan", "ROBOTLASER1/odom": "sensors/odom"}
    assert "ROBOTLASER1 feeds sensors/scan" in rec.left_out["FLASER"]
    assert "--remap ODOM=sensors/odom" in rec.left_out["ODOM"]
    rec = open_recording(write(tmp_path / "b.log", lines[:3]))
    assert rec.mapping == {"FLASER": "sensors/scan", "FLASER/odom": "sensors/odom"}
    rec = open_recording(tmp_path / "b.log", {"RLASER": "sensors/scan", "ODOM": "sensors/odom"})
    assert rec.mapping == {"RLASER": "sensors/scan", "ODOM": "sensors/odom"}
    got = [(topic, m.frame_id) for _, topic, m in rec.messages()]
    assert got == [("sensors/odom", "odom"), ("sensors/scan", "rear_laser")]
    rear_only = write(tmp_path / "c.log", [lines[0], lines[1]])
    assert open_recording(rear_only).mapping == {"RLASER": "sensors/scan",
                                                 "RLASER/odom": "sensors/odom"}  # fmt: skip
    with pytest.raises(RecordingError, match="ODOM gives Odometry; sensors/scan takes LaserScan"):
        open_recording(tmp_path / "b.log", {"ODOM": "sensors/scan"})
    with pytest.raises(RecordingError, match=r"no source \['LASER3'\] in the CARMEN log; it has"):
        open_recording(tmp_path / "b.log", {"LASER3": "sensors/scan"})


def test_track_without_topics_takes_the_recordings_own_scans_and_odometry(tmp_path):
    from recordings import write_recording

    from followbot.track import open_with_defaults

    log = write(tmp_path / "a.log", [odom(0, 0, 0, 0, 0, T0), flaser([1.0] * 180, stamp(1))])
    assert open_with_defaults(str(log), {}).mapping == {
        "FLASER": "sensors/scan", "FLASER/odom": "sensors/odom"
    }  # fmt: skip
    assert open_with_defaults(str(log), {"ODOM": "sensors/odom"}).mapping == {
        "FLASER": "sensors/scan", "ODOM": "sensors/odom"
    }  # fmt: skip
    # a followbot recording of scans, odometry, targets and commands: the sensor input only
    mcap = write_recording(tmp_path / "r.mcap", chunks=1, scans_per_chunk=3).path
    assert open_with_defaults(str(mcap), {}).mapping == {
        "sensors/scan": "sensors/scan", "sensors/odom": "sensors/odom"
    }  # fmt: skip
    odom_only = write(tmp_path / "b.log", [odom(0, 0, 0, 0, 0, T0)])
    with pytest.raises(RecordingError, match="no topic of it feeds sensors/scan by default"):
        open_with_defaults(str(odom_only), {})


def test_carmen_files_are_known_by_their_name_or_their_first_lines(tmp_path):
    lines = [flaser([1.0] * 180, T0)]
    for name in ("run.clf", "run.log", "run.LOG.txt", "run.clf.gz"):
        path = write(tmp_path / name, lines, gz=name.endswith(".gz"))
        assert open_recording(path).kind == "carmen", name
    path = write(tmp_path / "notes.txt", ["# CARMEN Logfile", *lines])
    assert open_recording(path).kind == "carmen"
    other = tmp_path / "service.log"
    other.write_text("2026-01-01 12:00:00 INFO started\nERROR something\n")
    with pytest.raises(RecordingError, match="no CARMEN laser or odometry records"):
        open_recording(other)
    text = tmp_path / "notes2.txt"
    text.write_text("hello\n")
    with pytest.raises(RecordingError, match="not a recording followbot reads"):
        open_recording(text)


# ----------------------------------------------------------------------------- bad lines


def _bad_log(tmp_path):
    good = [flaser(np.full(180, 3.0), stamp(k)) for k in range(4)]
    cut = flaser(np.full(180, 3.0), stamp(9))
    return write(tmp_path / "bad.log", [
        good[0],                                                      # 1
        odom(0, 0, 0, 0, 0, stamp(0.5)),                              # 2
        cut[: len(cut) // 2],                                         # 3 truncated
        good[1],                                                      # 4
        flaser([3.0] * 90 + [float("nan")] + [3.0] * 89, stamp(1.5)), # 5 NaN range
        "ODOM 1.2.3 0 0 0 0 0 " + stamp(1.6) + " host 0",            # 6 garbage number
        "NEFF 30",                                                    # 7 unknown record
        "\x00\x00\x00\x01garbage",                                    # 8 not a record
        good[2],                                                      # 9
        odom(0, 0, 0, 0, 0, "-3.5"),                                  # 10 negative stamp
        "FLASER abc 1 2 3",                                           # 11 bad count
        good[3] + " extra",                                           # 12 too many fields
    ])  # fmt: skip


def test_malformed_lines_are_skipped_counted_and_named_by_line(tmp_path):
    path = _bad_log(tmp_path)
    rec = open_recording(path)
    assert rec.contents["FLASER"] == ("LaserScan", 3)
    assert rec.contents["NEFF"] == ("-", 1)  # an unknown record: ignored, counted
    assert "not a CARMEN record followbot knows" in rec.left_out["NEFF"]
    [warning] = rec.warnings
    assert warning.startswith("skipped 7 of 12 lines it could not read: ")
    for part in ("1 truncated (line 3; e.g. FLASER: 105 fields, a FLASER of 180 beams needs 190)",
                 "1 not a finite number (line 5; e.g. FLASER: 'nan')",
                 "1 not a number (line 6; e.g. ODOM: '1.2.3')",
                 "1 not a CARMEN record (line 8;",
                 "1 bad timestamp (line 10; e.g. ODOM: '-3.5' (negative))",
                 "1 bad count (line 11; e.g. FLASER: beam count 'abc')",
                 "1 too many fields (line 12;"):  # fmt: skip
        assert part in warning, part
    scans = [m for _, topic, m in rec.messages() if topic == "sensors/scan"]
    assert [m.stamp_ns for m in scans] == [ns(0), ns(1), ns(2)]

    info = followbot("replay", str(path), "--info")
    assert info.returncode == 0, info.stderr
    assert f"warning: {path}: skipped 7 of 12 lines it could not read" in info.stderr


_GOOD_LINES = [
    odom(1.0, 2.0, 0.5, 0.3, 0.1, T0),
    flaser([1.5, 2.5, 81.91, 3.0], T0),
    flaser([1.5, 2.5, 3.0], T0, name="RLASER"),
    f"LASER3 3 1 2 3 {T0} host {T0}",
    robotlaser([1.0, 2.0, 3.0], [5.0, 6.0, 7.0], T0),
    rawlaser([1.0, 2.0], T0),
]
_NASTY = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e999", "-1", "0", "1e308", "3.5e38", "abc", "\xb2",
                     "99999999999", "-0", "1_0", "0x10", "1e-400", "1e999999999", "7", "4000"]),
    st.text(alphabet=st.characters(max_codepoint=255, exclude_characters="\n\r"), max_size=8),
)  # fmt: skip


@st.composite
def _damaged_line(draw):
    tokens = draw(st.sampled_from(_GOOD_LINES)).split()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(tokens) - 1))
        match draw(st.sampled_from(["replace", "delete", "insert"])):
            case "replace":
                tokens[i] = draw(_NASTY)
            case "delete" if len(tokens) > 1:
                del tokens[i]
            case "insert":
                tokens.insert(i, draw(_NASTY))
    line = " ".join(tokens)
    return line[: draw(st.integers(0, len(line)))] if draw(st.booleans()) else line


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(_damaged_line(), min_size=1, max_size=6))
def test_no_damaged_line_escapes_the_reader(lines):
    """Whatever a line holds, it is read or counted as malformed: never an exception, never an
    invalid message."""
    import tempfile
    from pathlib import Path

    from followbot.schemas import encode

    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp) / "fuzz.log", [*_GOOD_LINES, *lines])
        log = CarmenLog(path)
        assert sum(n for _, n in log.contents.values()) + log.bad.total >= len(_GOOD_LINES)
        for _, _, message in log.messages(list(log.contents)):
            assert decode(type(message), encode(message)) is not None  # valid on the wire


def test_files_with_nothing_readable_are_clear_errors(tmp_path):
    empty = tmp_path / "empty.log"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"no CARMEN laser or odometry records \(no records"):
        open_recording(empty)
    noise = tmp_path / "noise.log"
    noise.write_bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(
        RecordingError, match=r"no CARMEN laser or odometry records.*could not read"
    ):
        open_recording(noise)
    bad_gzip = tmp_path / "bad.log.gz"
    bad_gzip.write_bytes(b"\x1f\x8b\x08\x00" + bytes(range(256)) * 4)
    with pytest.raises(RecordingError, match="unreadable gzip data after line 0"):
        open_recording(bad_gzip)
    out = followbot("replay", str(bad_gzip), "--info")
    assert out.returncode == 2 and "unreadable gzip data" in out.stderr


def test_many_bad_lines_show_the_first_five_line_numbers(tmp_path):
    lines = [flaser([1.0] * 180, stamp(k)) for k in range(3)]
    lines += [f"ODOM 0 0 0 0 0 0 {stamp(5 + k)}" for k in range(8)]  # no host: truncated
    rec = open_recording(write(tmp_path / "m.log", lines))
    assert "8 truncated (lines 4, 5, 6, 7, 8, ...; e.g. ODOM:" in rec.warnings[0]


def test_readings_at_the_scanners_ceiling_mean_no_return(tmp_path):
    def ranges_of(lines):
        rec = open_recording(write(tmp_path / "c.log", lines))
        return rec.carmen.no_return_m["FLASER"], [m.ranges_m() for _, t, m in rec.messages()
                                                  if t == "sensors/scan"]  # fmt: skip

    # SICK's no-return readings (81.83-81.91) and CARMEN's 80 m
    ceiling, scans = ranges_of([flaser([81.91, 80.0, 79.99, 1.0], T0)])
    assert ceiling == 80.0
    np.testing.assert_array_equal(scans[0], np.array([np.inf, np.inf, 79.99, 1.0], np.float32))
    # a converter that wrote 50 m for no return: readings pile up there, at least one per ten
    # scans; readings within 0.1 m of the file's largest mean no return
    lines = [flaser([50.0 if k % 5 == 0 else 3.0, 49.95, 49.8, 2.0], stamp(k)) for k in range(20)]
    ceiling, scans = ranges_of(lines)
    assert ceiling == pytest.approx(49.9)
    np.testing.assert_array_equal(scans[0], np.array([np.inf, np.inf, 49.8, 2.0], np.float32))
    # one far reading in twenty scans is a far wall, not a ceiling
    lines = [flaser([30.0 if k == 3 else 3.0, 2.0], stamp(k)) for k in range(20)]
    ceiling, scans = ranges_of(lines)
    assert ceiling == 80.0 and scans[3][0] == np.float32(30.0)
    # nor is an indoor scan's farthest wall, however often it repeats
    ceiling, scans = ranges_of([flaser([6.5, 6.5, 2.0], stamp(k)) for k in range(20)])
    assert ceiling == 80.0 and np.isfinite(scans[0]).all()


# ----------------------------------------------------------------------------- gzip, clocks


def test_a_gzipped_log_reads_as_the_plain_one_and_a_cut_one_up_to_the_cut(tmp_path):
    rng = np.random.default_rng(1)
    lines = []
    for k in range(60):
        lines += [odom(0.01 * k, 0, 0, 0.1, 0, stamp(k - 0.5)),
                  flaser(np.round(rng.uniform(0.5, 8, 361), 2), stamp(k))]  # fmt: skip
    plain, zipped = write(tmp_path / "r.log", lines), write(tmp_path / "r.log.gz", lines, gz=True)

    def scans(path):
        rec = open_recording(path)
        return rec, [(m.stamp_ns, m.ranges_m().tobytes()) for _, t, m in rec.messages()
                     if t == "sensors/scan"]  # fmt: skip

    assert scans(zipped)[1] == scans(plain)[1] and len(scans(plain)[1]) == 60
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(zipped.read_bytes()[: zipped.stat().st_size * 6 // 10])
    rec, got = scans(cut)
    assert 20 < len(got) < 60
    assert got == scans(plain)[1][: len(got)]
    assert rec.damage is not None and "the gzip stream ends early" in rec.damage.reason
    assert "cut short" in rec.damage.describe()
    info = followbot("replay", str(cut), "--info")
    assert info.returncode == 0 and f"warning: {cut} is damaged: read" in info.stderr


def test_scans_whose_stamps_do_not_increase_are_restamped_and_odom_lines_left_out(tmp_path):
    lines = []
    for k in range(10):  # the logger wrote 0 for every scan (as in orebro-corrected.log)
        lines += [odom(k, 0, 0, 0, 0, stamp(k + 0.5)), flaser([2.0] * 181, "0", odom=(k, 0, 0))]
    path = write(tmp_path / "r.log", lines)
    rec = open_recording(path)
    assert rec.mapping == {"FLASER": "sensors/scan", "FLASER/odom": "sensors/odom"}
    assert "another clock" in rec.left_out["ODOM"]
    assert rec.warnings == [
        "FLASER: 10 of its 10 scans are stamped 0 or no later than an earlier scan (stamps "
        "0..0 s); "
        "they are restamped 1 s apart in file order"
    ]
    got = [(t, topic, m.x_m if topic == "sensors/odom" else None) for t, topic, m in
           rec.messages()]  # fmt: skip
    second = 1_000_000_000
    assert got == [
        x
        for k in range(10)
        for x in ((second * (k + 1), "sensors/odom", k), (second * (k + 1), "sensors/scan", None))
    ]
    with pytest.raises(RecordingError, match="cannot be replayed together"):
        open_recording(path, {"ODOM": "sensors/odom"})


def test_a_few_scans_out_of_order_are_left_out_and_counted(tmp_path):
    stamps = [stamp(k) for k in range(20)]
    stamps[12] = stamps[11]  # one scan in twenty: the clock is otherwise good
    lines = [flaser([2.0] * 180, t) for t in stamps]
    lines += [odom(0, 0, 0, 0, 0, "0"), odom(0, 0, 0, 0, 0, stamp(20))]
    rec = open_recording(write(tmp_path / "r.log", lines), {"ODOM": "sensors/odom"})
    assert rec.warnings == []
    scans = [m.stamp_ns for _, t, m in rec.messages() if t == "sensors/scan"]
    assert len(scans) == 19 and scans == sorted(set(scans))
    assert rec.skipped == {
        "FLASER: stamped 0 or no later than an earlier FLASER scan": 1,
        "ODOM: stamped 0 or no later than an earlier ODOM line": 1,
    }


# ----------------------------------------------------------------------------- real logs


@needs_data
@pytest.mark.parametrize("log", ["aces", "orebro", "freiburg-101", "seattle"])
def test_the_beam_geometry_fits_the_corrected_poses_better_than_the_alternatives(log):
    """Scans put into the map at their corrected poses: with the reader's geometry, walls seen
    from different places lie closer together than with any other reading of the beam count
    (180, 181, 360, 361 beams; figures in docs/recording.md)."""
    scans = flaser_scans(CARMEN / f"{log}-corrected.log.gz")
    n = len(scans[0].ranges)
    fits = {name: residual_m(scans, *geometry) for name, geometry in candidates(n).items()}
    chosen = next(name for name in fits if "(chosen)" in name)
    assert candidates(n)[chosen] == flaser_geometry(n)
    for name, residual in fits.items():
        if name != chosen:
            assert fits[chosen] < residual, (name, fits)
    assert fits[chosen] < 0.05  # metres: the map is sharp


@needs_data
def test_replay_info_lists_a_real_logs_sources(tmp_path):
    path = CARMEN / "aces-corrected.log.gz"
    info = followbot("replay", str(path), "--info")
    assert info.returncode == 0, info.stderr
    lines = info.stderr.splitlines()
    assert any(line.split()[:4] == ["FLASER", "LaserScan", "440", "->"] for line in lines)
    assert any(line.split()[:4] == ["FLASER/odom", "Odometry", "440", "->"] for line in lines)
    assert "replaying FLASER, FLASER/odom; skipping NEFF, ODOM, PARAM" in info.stderr


@needs_data
@pytest.mark.multiprocess
def test_track_runs_on_a_real_carmen_log_with_its_default_sources(tmp_path):
    path = CARMEN / "aces-corrected.log.gz"
    out = subprocess.run(
        [sys.executable, "-m", "followbot", "track", str(path), "--output", str(tmp_path),
         "--max-scans", "100"], capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "FLASER -> sensors/scan" in out.stderr and "FLASER/odom -> sensors/odom" in out.stderr
    assert "tracked 100 scans" in out.stdout
    for name in ("tracks.mcap", "people.csv", "target.csv"):
        assert (tmp_path / name).stat().st_size > 0
    # every scan answered and kept, the gaps of up to 38 s between them notwithstanding
    answers = {m.stamp_ns for _, t, m in open_recording(tmp_path / "tracks.mcap").messages()
               if t == "tracking/people"}  # fmt: skip
    assert len(answers) == 100
    with (tmp_path / "people.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["stamp_ns", "id", "x_m", "y_m", "vx_mps", "vy_mps", "frame"]
    assert "laser mount: x 0.000 m, y 0.000 m, yaw 0.0 deg (none in the recording" in out.stderr
    # answers to the log's scans, on the log's clock
    scan_stamps = {m.stamp_ns for _, t, m in open_recording(path).messages()
                   if t == "sensors/scan"}  # fmt: skip
    assert {int(r[0]) for r in rows[1:]} <= scan_stamps


@pytest.mark.multiprocess
def test_a_carmen_log_replays_over_zenoh(tmp_path, endpoint, robot, zenoh_session):
    lines = [flaser([81.91] + [2.0] * 179, stamp(0.1 * k)) for k in range(20)]
    lines.insert(5, "FLASER 180 1 2 3")  # truncated
    path = write(tmp_path / "z.log.gz", lines, gz=True)
    got: queue.SimpleQueue = queue.SimpleQueue()
    sub = zenoh_session.declare_subscriber(
        Keys(robot).topic("sensors/scan"), lambda s: got.put(s.payload.to_bytes())
    )
    out = followbot("replay", str(path), "--connect", endpoint, "--robot", robot,
                    "--rate", "0", "--wait", "10", timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    time.sleep(0.5)
    sub.undeclare()
    scans = []
    while not got.empty():
        scans.append(decode(LaserScan, got.get()))
    assert [s.stamp_ns for s in scans] == [ns(0.1 * k) for k in range(20)]
    assert all(s.ranges_m()[0] == np.inf and s.ranges_m()[1] == np.float32(2.0) for s in scans)
    assert "replayed 40 messages" in out.stdout  # scans and their odometry
    last = out.stderr.strip().splitlines()[-1]
    assert last == (f"warning: {path}: skipped 1 of 21 lines it could not read: 1 truncated "
                    "(line 6; e.g. FLASER: 5 fields, a FLASER of 180 beams needs 190)")  # fmt: skip
