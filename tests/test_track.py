"""followbot track: a real recording through the real pipeline, deterministically; and the
round trip sim -> record -> track giving the tracks of the live run."""

from __future__ import annotations

import csv
import subprocess
import sys
from importlib import resources

import msgspec
import numpy as np
import pytest
import yaml
from conftest import SHARED_DATA

from followbot.bags import open_recording

MS = 1_000_000

DEMO_BAG = SHARED_DATA / "leg_tracker" / "demo_stationary_simple_environment.bag"
needs_data = pytest.mark.skipif(
    not DEMO_BAG.is_file(), reason=f"leg_tracker data absent at {DEMO_BAG}"
)


def track(out, *extra, recording=DEMO_BAG, scan_topic="/scan", max_scans=250):
    limit = ["--max-scans", str(max_scans)] if max_scans else []
    return subprocess.run(
        [sys.executable, "-m", "followbot", "track", str(recording), "--scan-topic", scan_topic,
         "--output", str(out), *limit, *extra],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip


def rows(path):
    with path.open() as f:
        return list(csv.reader(f))


@needs_data
@pytest.mark.multiprocess
def test_a_ros1_bag_is_tracked_end_to_end_and_deterministically(tmp_path):
    a, b = track(tmp_path / "a"), track(tmp_path / "b")
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    assert "tracked 250 scans" in a.stdout
    # the bag has no odometry: laser_odometry estimates it, in lock-step like the others
    assert "laser_odometry estimates it from the scans" in a.stderr
    assert (tmp_path / "a" / "laser_odometry.log").is_file()
    assert "did not answer in time" not in a.stdout
    people, target = rows(tmp_path / "a" / "people.csv"), rows(tmp_path / "a" / "target.csv")
    assert people[0] == ["stamp_ns", "id", "x_m", "y_m", "vx_mps", "vy_mps", "frame"]
    assert {r[6] for r in people[1:]} == {"base_link"}
    assert len(people) > 100 and len(target) > 20  # people walk round the still robot
    stamps = [int(r[0]) for r in target[1:]]
    assert stamps == sorted(stamps)
    assert all(abs(float(r[2])) < 30 and abs(float(r[3])) < 30 for r in people[1:])
    # the same recording gives the same tracks
    assert rows(tmp_path / "b" / "people.csv") == people
    assert rows(tmp_path / "b" / "target.csv") == target
    assert (tmp_path / "a" / "tracks.mcap").stat().st_size > 10_000


@needs_data
@pytest.mark.multiprocess
def test_missing_topics_and_bad_settings_are_clear_errors(tmp_path):
    out = track(tmp_path, "--odom-topic", "/odom")
    assert out.returncode == 2 and "no topic ['/odom']" in out.stderr
    out = track(tmp_path, "--set", "nope.detector=x")
    assert out.returncode == 2 and "SERVICE.KEY=VALUE" in out.stderr


def outputs(path, topics=("tracking/target", "tracking/people")):
    """(topic, stamp) -> the message on one of ``topics``, ``seq`` left out."""
    out = {}
    for _, topic, m in open_recording(path).messages():
        if topic in topics:
            assert (topic, m.stamp_ns) not in out, f"two {topic} for stamp {m.stamp_ns}"
            out[topic, m.stamp_ns] = {**msgspec.to_builtins(m), "seq": None}
    return out


def first_difference(a, b):
    assert a.keys() == b.keys()
    differ = sorted((k for k in a if a[k] != b[k]), key=lambda k: (k[1], k[0]))
    return f"{len(differ)} differ, first {differ[0]}: {a[differ[0]]} != {b[differ[0]]}"


@pytest.mark.multiprocess
def test_lockstep_runs_and_the_track_of_their_recording_give_the_same_tracks(tmp_path):
    """sim -> record -> track: every stage its own process each time, the same tracks to the
    last bit; and two live runs alike, commands included (docs/recording.md, "Round trip")."""
    from followbot.runner import run_scenario

    # the target and a bystander walk off side by side; the robot follows
    builtin = resources.files("followbot.services.sim").joinpath("scenarios")
    spec = yaml.safe_load(builtin.joinpath("thesis_5_2_4_turn_apart.yaml").read_text())
    spec["duration_s"] = 7.0
    scenario = tmp_path / "turn_apart_7s.yaml"
    scenario.write_text(yaml.safe_dump(spec))
    runs = [
        run_scenario(str(scenario), "thesis", tmp_path / name, vision=False, progress=False)
        for name in ("a", "b")
    ]
    for run in runs:
        assert not any(run.timeouts.values()), run.timeouts
    recording = tmp_path / "a" / "run.mcap"
    out = track(tmp_path / "track", "--odom-topic", "sensors/odom", "--preset", "thesis",
                recording=recording,
                scan_topic="sensors/scan", max_scans=None)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "did not answer" not in out.stdout

    robot = [m for _, t, m in open_recording(recording).messages() if t == "sensors/odom"]
    assert robot[-1].x_m - robot[0].x_m > 0.2  # it moved: odometry matters
    live = outputs(recording)
    assert len(live) == 2 * len(runs[0].records) > 100
    assert any(m["status"] == "tracking" for (t, _), m in live.items() if t.endswith("target"))
    replayed = outputs(tmp_path / "track" / "tracks.mcap")
    assert replayed == live, first_difference(live, replayed)
    commands = ("tracking/target", "tracking/people", "control/cmd_vel", "control/pan")
    a, b = outputs(recording, commands), outputs(tmp_path / "b" / "run.mcap", commands)
    assert a == b, first_difference(a, b)


@pytest.mark.multiprocess
def test_two_lockstep_runs_with_vision_give_the_same_tracks(tmp_path):
    """With vision as its own process too: verifications, tracks and commands alike, run to run
    (vision pairs each scan with the image due at it, whichever arrives first)."""
    from followbot.runner import run_scenario

    builtin = resources.files("followbot.services.sim").joinpath("scenarios")
    spec = yaml.safe_load(builtin.joinpath("thesis_5_2_4_two_people.yaml").read_text())
    spec["duration_s"] = 9.0  # acquisition at ~3 s, the crossing at ~6 s
    scenario = tmp_path / "two_people_9s.yaml"
    scenario.write_text(yaml.safe_dump(spec))
    runs = [
        run_scenario(str(scenario), "thesis", tmp_path / name, progress=False, record=False)
        for name in ("a", "b")
    ]

    def answers(run):
        out = {}
        for r in run.records:
            for name in ("verification", "target", "people", "cmd"):
                m = getattr(r, name)
                out[(r.stamp_ns, name)] = None if m is None else msgspec.structs.replace(m, seq=0)
        return out

    a, b = answers(runs[0]), answers(runs[1])
    assert any(v is not None and v.chosen >= 0 for (_, n), v in a.items() if n == "verification")
    assert a == b, next(k for k in a if a[k] != b.get(k))


def test_laser_odometry_runs_when_the_recording_has_no_odometry_unless_switched_off():
    from followbot.track import tracking_settings, use_laser_odometry

    assert use_laser_odometry("auto", False) and not use_laser_odometry("auto", True)
    assert use_laser_odometry("on", True) and not use_laser_odometry("off", False)
    stages = ["laser_legs", "tracker"]
    s = tracking_settings("thesis", stages, False, ["laser_odometry.keyframe_distance_m=0.5"],
                          odometry=False, laser_odometry=True)  # fmt: skip
    assert s["laser_odometry"]["keyframe_distance_m"] == 0.5
    # the stages wait for its odometry as for a recording's (lock-step rule 5)
    assert s["tracker"]["lockstep_odometry_wait_s"] > 0
    assert s["laser_legs"]["lockstep_odometry_wait_s"] > 0
    off = tracking_settings("thesis", stages, False, [], odometry=False)
    assert "laser_odometry" not in off and "lockstep_odometry_wait_s" not in off["tracker"]


def test_odometry_goes_out_before_the_scan_it_brackets():
    """Rule 5: a scan is sent once odometry stamped at or after it has gone out."""
    from followbot.schemas import Image, LaserScan, Odometry
    from followbot.track import odometry_ahead

    def scan(ms):
        ranges = np.ones(3, np.float32)
        return "sensors/scan", LaserScan(stamp_ns=ms * MS, angle_min_rad=0.0, ranges=ranges,
                                         angle_increment_rad=0.1, range_min_m=0.0,
                                         range_max_m=10.0)  # fmt: skip

    def odom(ms):
        return "sensors/odom", Odometry(stamp_ns=ms * MS, x_m=0.0, y_m=0.0, yaw_rad=0.0)

    def image(ms):
        return "sensors/image", Image.from_array(np.zeros((2, 2, 3), np.uint8), stamp_ns=ms * MS)

    def order(stream, **kw):
        return [(t.split("/")[1], m.stamp_ns // MS) for t, m in odometry_ahead(stream, **kw)]

    # odometry at 30 ms, scans every 100 ms: each scan waits for the next odometry; an image
    # after the scan stays after it
    stream = [odom(60), odom(90), scan(100), image(100), odom(120), odom(150), scan(200),
              odom(210)]  # fmt: skip
    assert order(stream) == [
        ("odom", 60), ("odom", 90), ("odom", 120), ("scan", 100), ("image", 100),
        ("odom", 150), ("odom", 210), ("scan", 200),
    ]  # fmt: skip
    # odometry at the scan's own stamp (the simulator's): nothing moves
    aligned = [odom(80), odom(100), scan(100), odom(120)]
    assert order(aligned) == [("odom", 80), ("odom", 100), ("scan", 100), ("odom", 120)]
    # a gap in the odometry: a scan waits only until the recording is a horizon past it
    gap = [odom(0), scan(100), scan(200), odom(250), scan(300)]
    assert order(gap, horizon_ns=120 * MS) == [
        ("odom", 0), ("scan", 100), ("odom", 250), ("scan", 200), ("scan", 300),
    ]  # fmt: skip


@pytest.mark.multiprocess
def test_a_cut_recording_is_tracked_up_to_the_cut(tmp_path):
    from recordings import write_recording

    layout = write_recording(tmp_path / "whole.mcap")
    offset = (layout.chunk_ends[4] + layout.chunk_ends[5]) // 2
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(layout.path.read_bytes()[:offset])
    n = layout.scans_before(offset)
    out = track(tmp_path / "out", "--odom-topic", "sensors/odom", recording=cut,
                scan_topic="sensors/scan", max_scans=None)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert f"tracked {n} scans" in out.stdout
    assert "is damaged: read" in out.stderr and "cut short" in out.stderr
    people = rows(tmp_path / "out" / "people.csv")[1:]
    assert {int(r[0]) for r in people} <= {m.stamp_ns for _, t, m in open_recording(cut).messages()
                                           if t == "sensors/scan"}  # fmt: skip
    # the summary counts track ids, and says so; it claims no number of people
    ids = {r[1] for r in people}
    plural = "" if len(ids) == 1 else "s"
    assert ids and f"{len(ids)} person track{plural} (distinct track ids)" in out.stdout
    assert " people" not in out.stdout


def test_a_bad_stage_setting_is_refused_before_any_stage_starts(tmp_path):
    from recordings import write_recording

    recording = write_recording(tmp_path / "run.mcap", chunks=1).path
    out = track(tmp_path / "out", "--set", "tracker.bogus=1", "--set", "laser_legs.detector=nope",
                recording=recording, scan_topic="sensors/scan")  # fmt: skip
    assert out.returncode == 2
    assert "tracker: settings: Object contains unknown field `bogus`" in out.stderr
    assert "laser_legs: settings: detector: unknown detector 'nope'; valid names:" in out.stderr
    assert not (tmp_path / "out").exists()  # no stage was started (each would log there)
