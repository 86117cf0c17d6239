"""The laser's mount on the base (laser_mount): the transforms, and the real pipeline with a
laser mounted off-centre and turned."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from followbot.schemas import Candidate, Leg, PersonCandidates
from followbot.services.runtime.mount import (
    BASE_FRAME,
    LaserMount,
    candidates_in_base,
    parse_laser_pose,
)
from followbot.services.runtime.settings import NodeSettings, SettingsError, load_settings

MOUNT = LaserMount(x_m=0.5, y_m=-0.2, yaw_deg=40.0)
LASER = {"mount_x_m": 0.5, "mount_y_m": -0.2, "mount_yaw_deg": 40.0}


def test_laser_and_base_frames_are_each_other_s_inverse():
    rng = np.random.default_rng(1)
    p = rng.uniform(-5, 5, (20, 2))
    assert MOUNT.to_laser(MOUNT.to_base(p)) == pytest.approx(p)
    # the laser's own origin is the mount point; its +x axis points 40 deg left of the base's
    assert MOUNT.to_base([0.0, 0.0])[0] == pytest.approx([0.5, -0.2])
    ahead = MOUNT.to_base([1.0, 0.0])[0] - MOUNT.to_base([0.0, 0.0])[0]
    assert math.degrees(math.atan2(ahead[1], ahead[0])) == pytest.approx(40.0)
    assert LaserMount().is_identity and not MOUNT.is_identity


def test_candidates_are_turned_into_the_base_frame_with_their_range_and_bearing():
    legs = [
        Leg(x_m=2.0, y_m=0.1, first_beam=0, last_beam=2),
        Leg(x_m=2.0, y_m=-0.1, first_beam=4, last_beam=6),
    ]
    cand = Candidate(x_m=2.0, y_m=0.0, range_m=2.0, bearing_rad=0.0, legs=legs)
    msg = PersonCandidates(stamp_ns=1, frame_id="laser", n_beams=10, candidates=[cand])
    out = candidates_in_base(msg, MOUNT)
    c = out.candidates[0]
    x, y = MOUNT.to_base([2.0, 0.0])[0]
    assert (c.x_m, c.y_m) == pytest.approx((x, y))
    assert c.range_m == pytest.approx(math.hypot(x, y))
    assert c.bearing_rad == pytest.approx(math.atan2(y, x))
    moved = [[leg.x_m, leg.y_m] for leg in c.legs]
    assert np.allclose(moved, MOUNT.to_base([[2.0, 0.1], [2.0, -0.1]]))
    assert out.frame_id == BASE_FRAME and msg.candidates[0].x_m == 2.0  # a copy
    same = candidates_in_base(msg, LaserMount())
    assert same.candidates == msg.candidates and same.frame_id == BASE_FRAME


def test_the_laser_pose_option_reads_x_y_and_degrees_and_says_its_form_when_wrong():
    assert parse_laser_pose("0.88, 0, 42") == LaserMount(x_m=0.88, y_m=0.0, yaw_deg=42.0)
    for bad in ("0.88,0", "a,b,c", "0,0,nan", "0,0,720"):
        with pytest.raises(ValueError, match="expected x,y,yaw_deg"):
            parse_laser_pose(bad)


def test_laser_mount_is_a_setting_of_every_service_checked_when_it_loads(tmp_path):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("laser_mount: {x_m: 0.88, yaw_deg: 42}\n")
    assert load_settings(NodeSettings, cfg).laser_mount == LaserMount(x_m=0.88, yaw_deg=42.0)
    cfg.write_text("laser_mount: {x: 0.88}\n")
    with pytest.raises(SettingsError, match="laser_mount"):
        load_settings(NodeSettings, cfg)


def test_a_compose_file_s_laser_mount_reaches_every_service(tmp_path):
    from followbot.services.runtime.compose import load_compose, service_settings

    f = tmp_path / "c.yaml"
    f.write_text(
        "laser_mount: {x_m: 0.88, y_m: 0, yaw_deg: 42}\n"
        "services: {laser_legs: {}, tracker: {process: core}, controller: {process: core}}\n"
    )
    compose = load_compose(f)
    for name in ("laser_legs", "tracker", "controller"):
        assert service_settings(compose, name)["laser_mount"] == {
            "x_m": 0.88,
            "y_m": 0,
            "yaw_deg": 42,
        }


def test_the_simulator_refuses_a_laser_mount_that_is_not_its_scenario_s(tmp_path):
    from followbot.services.sim.node import SimSettings, check

    scenario = _standing_scenario(tmp_path)
    with pytest.raises(ValueError, match=r"its laser sits at x 0\.500 m, y -0\.200 m, yaw 40\.0"):
        check(SimSettings(scenario=str(scenario)))
    check(SimSettings(scenario=str(scenario), laser_mount=MOUNT))


def _standing_scenario(tmp_path, duration_s: float = 8.0):
    """One person standing 2.6 m ahead and 1.6 m left of the robot; the laser 0.5 m ahead,
    0.2 m right of the base's centre and turned 40 deg left. The controller turns the robot
    towards the person and drives up to them."""
    spec = {
        "name": "mounted_laser",
        "duration_s": duration_s,
        "seed": 3,
        "world": {"walls": [{"points": [[-3, -4], [8, -4], [8, 6], [-3, 6]], "closed": True}]},
        "laser": LASER,
        "people": [{"id": 1, "is_target": True, "start": [2.6, 1.6], "heading_deg": 180.0}],
    }
    path = tmp_path / "mounted_laser.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def _world_errors(run) -> tuple[list[float], float, float]:
    """Per scan with the target tracked: how far the tracker's estimate (base frame), mapped to
    the world by the robot's true pose, lies from where the person stands; and how far the
    robot drove and turned."""
    errors = []
    for r in run.records:
        t = r.target
        if t is None or t.status != "tracking":
            continue
        g = r.truth
        c, s = math.cos(g.robot_yaw_rad), math.sin(g.robot_yaw_rad)
        wx = g.robot_x_m + c * t.x_m - s * t.y_m
        wy = g.robot_y_m + s * t.x_m + c * t.y_m
        person = next(p for p in g.people if p.is_target)
        errors.append(math.hypot(wx - person.x_m, wy - person.y_m))
    first, last = run.records[0].truth, run.records[-1].truth
    driven = math.hypot(last.robot_x_m - first.robot_x_m, last.robot_y_m - first.robot_y_m)
    turned = abs(math.degrees(last.robot_yaw_rad - first.robot_yaw_rad))
    return errors, driven, turned


@pytest.mark.parametrize("stages_told", [True, False], ids=["mount_given", "mount_not_given"])
def test_a_standing_person_stays_still_in_the_world_with_the_laser_off_centre_and_turned(
    tmp_path, stages_told
):
    """The real pipeline (sim, laser_legs, tracker, controller: one process each, lock-step):
    the robot turns towards a standing person and drives up to them. With laser_mount given
    (followbot eval passes the scenario's), the tracker's estimate stays within 0.2 m of where
    the person stands in the world the whole way (the detector's person centre alone is off by
    up to ~0.15 m, with a laser at the base's centre too: 0.13 m median there, 0.08 m here).
    The control: the stages told the laser sits at the base's centre, facing ahead (the sim's
    laser unchanged), place the person 0.5-1.6 m off, moving as the robot turns."""
    from followbot.runner import run_scenario

    scenario = _standing_scenario(tmp_path)
    wrong = "laser_mount={x_m: 0, y_m: 0, yaw_deg: 0}"
    overrides = [] if stages_told else [f"{s}.{wrong}" for s in ("laser_legs", "tracker")]
    run = run_scenario(
        str(scenario), "thesis", tmp_path / "run", vision=False, progress=False, record=False,
        overrides=overrides,
    )  # fmt: skip
    assert not any(run.timeouts.values()), run.timeouts
    errors, driven, turned = _world_errors(run)
    assert len(errors) > 0.8 * len(run.records)  # tracked nearly throughout
    if stages_told:
        assert driven > 0.8 and turned > 15.0, (driven, turned)  # it drove and turned
        assert max(errors) < 0.2, errors
    else:
        assert min(errors) > 0.3 and max(errors) - min(errors) > 0.5, errors


# --------------------------------------------------------------------------- recordings


def _bag_with_tf(path, edges, scans: int = 5):
    """A ROS 1 bag: 10 Hz scans in frame ``laser`` on /scan, and ``edges`` ((parent, child,
    x, y, yaw_deg, roll_deg)) once on /tf_static."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    # tf2_msgs is not among rosbags' bundled types: its one-line definition
    store.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    t = store.types
    Header, Time = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
    Scan, Tf = t["sensor_msgs/msg/LaserScan"], t["tf2_msgs/msg/TFMessage"]
    Stamped, Transform = t["geometry_msgs/msg/TransformStamped"], t["geometry_msgs/msg/Transform"]
    Vector3, Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
    t0 = 1_700_000_000_000_000_000

    def header(stamp, frame):
        sec, nsec = divmod(stamp, 1_000_000_000)
        return Header(seq=0, stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    def quaternion(yaw_deg, roll_deg):  # roll about x, then yaw about z
        y, r = math.radians(yaw_deg) / 2, math.radians(roll_deg) / 2
        cy, sy, cr, sr = math.cos(y), math.sin(y), math.cos(r), math.sin(r)
        return Quaternion(x=cy * sr, y=sy * sr, z=sy * cr, w=cy * cr)

    tf = Tf(
        transforms=[
            Stamped(
                header=header(t0, parent),
                child_frame_id=child,
                transform=Transform(
                    translation=Vector3(x=x, y=y, z=0.3), rotation=quaternion(yaw, roll)
                ),
            )
            for parent, child, x, y, yaw, roll in edges
        ]
    )
    with Writer(path) as w:
        c_tf = w.add_connection("/tf_static", Tf.__msgtype__, typestore=store)
        c_scan = w.add_connection("/scan", Scan.__msgtype__, typestore=store)
        w.write(c_tf, t0, store.serialize_ros1(tf, Tf.__msgtype__))
        for i in range(scans):
            stamp = t0 + i * 100_000_000
            msg = Scan(
                header=header(stamp, "laser"), angle_min=-1.5, angle_max=1.5,
                angle_increment=3.0 / 299, time_increment=0.0, scan_time=0.1, range_min=0.02,
                range_max=8.0, ranges=np.full(300, 3.0, np.float32),
                intensities=np.zeros(0, np.float32),
            )  # fmt: skip
            w.write(c_scan, stamp, store.serialize_ros1(msg, Scan.__msgtype__))
    return path


CHAIN = [("base_link", "plate", 0.8, 0.0, 30.0, 0.0), ("plate", "laser", 0.08, 0.0, 12.0, 0.0)]


def test_the_mount_is_read_from_a_bag_s_tf_static_chained_in_2d(tmp_path):
    from followbot.bags import mount_from_tf

    bag = _bag_with_tf(tmp_path / "tf.bag", CHAIN)
    found = mount_from_tf(bag, "base_link", "laser")
    m = found.mount
    x, y = 0.8 + 0.08 * math.cos(math.radians(30)), 0.08 * math.sin(math.radians(30))
    assert (m.x_m, m.y_m, m.yaw_deg) == pytest.approx((x, y, 42.0))
    assert found.source == "/tf_static: base_link -> plate -> laser" and not found.warnings
    # asked the other way round, the chain is walked backwards: the inverse pose
    back = mount_from_tf(bag, "laser", "base_link").mount
    assert back.to_base(m.to_base([[1.0, 2.0]])) == pytest.approx(np.array([[1.0, 2.0]]))
    assert mount_from_tf(bag, "base_link", "camera") is None  # no chain: None
    tilted = _bag_with_tf(tmp_path / "tilt.bag", [("base_link", "laser", 0.2, 0, 0, 180.0)])
    assert "tilted (roll 180.0 deg" in mount_from_tf(tilted, "base_link", "laser").warnings[0]


def _track(bag, out, *extra):
    import subprocess
    import sys

    return subprocess.run(
        [sys.executable, "-m", "followbot", "track", str(bag), "--output", str(out),
         "--max-scans", "3", *extra],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip


@pytest.mark.multiprocess
def test_track_uses_the_bag_s_tf_mount_and_laser_pose_overrides_it(tmp_path):
    bag = _bag_with_tf(tmp_path / "tf.bag", CHAIN)
    out = _track(bag, tmp_path / "a")
    assert out.returncode == 0, out.stderr
    assert (
        "laser mount: x 0.869 m, y 0.040 m, yaw 42.0 deg "
        "(tf /tf_static: base_link -> plate -> laser)" in out.stderr
    )
    settings = yaml.safe_load((tmp_path / "a" / "tracker.settings.yaml").read_text())
    assert settings["laser_mount"] == pytest.approx({"x_m": 0.8693, "y_m": 0.04, "yaw_deg": 42.0},
                                                    abs=1e-3)  # fmt: skip
    out = _track(bag, tmp_path / "b", "--laser-pose", "0.5,-0.1,10")
    assert out.returncode == 0, out.stderr
    assert "laser mount: x 0.500 m, y -0.100 m, yaw 10.0 deg (--laser-pose)" in out.stderr
    settings = yaml.safe_load((tmp_path / "b" / "laser_legs.settings.yaml").read_text())
    assert settings["laser_mount"] == {"x_m": 0.5, "y_m": -0.1, "yaw_deg": 10.0}
    out = _track(bag, tmp_path / "c", "--laser-frame", "nowhere")
    assert "no tf joins base_link and nowhere" in out.stderr
    bad = _track(bag, tmp_path / "d", "--laser-pose", "0.5")
    assert bad.returncode == 2 and "expected x,y,yaw_deg" in bad.stderr


def test_a_carmen_log_s_robotlaser_records_give_the_laser_s_offset(tmp_path):
    from followbot.bags import open_recording
    from followbot.track import laser_mount_of

    # the robot at (4, 6) heading 90 deg; the laser 0.3 m ahead of it (so at (4, 6.3)),
    # turned 10 deg further
    yaw = math.radians(90.0)
    laser = (4.0, 6.3, yaw + math.radians(10.0))
    cfg = "0 -1.5 3.0 0.01 30.0 0.01 0"
    lines = []
    for i in range(3):
        r = " ".join(["2.0"] * 301)
        poses = " ".join(map(str, (*laser, 4.0, 6.0, yaw, 0.0, 0.0, 0.5, 0.3, 0.0)))
        t = f"{100 + i * 0.1:.1f}"
        lines.append(f"ROBOTLASER1 {cfg} 301 {r} 0 {poses} {t} host {t}")
    log = tmp_path / "robot.log"
    log.write_text("\n".join(lines) + "\n")
    rec = open_recording(log)
    mount, source = laser_mount_of(rec, None, "base_link", None)
    assert (mount.x_m, mount.y_m, mount.yaw_deg) == pytest.approx((0.3, 0.0, 10.0))
    assert source.startswith("ROBOTLASER1 records")
    given = parse_laser_pose("0.1,0,0")
    assert laser_mount_of(rec, given, "base_link", None) == (given, "--laser-pose")
