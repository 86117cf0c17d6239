"""laser_odometry's core: poses of a laser moving through a synthetic room come back, a still
laser stays still, and bad scans are counted, never raised."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from odometry_room import PERIOD_NS, room_scan, to_laser

from followbot.schemas import LaserScan
from followbot.services.laser_legs.scene import make_scan
from followbot.services.laser_odometry.core import ScanOdometry
from followbot.services.laser_odometry.settings import LaserOdometrySettings


def relative(p0, p1):
    """Pose p1 in the frame of pose p0."""
    x, y = to_laser(p0, p1[0], p1[1])
    return x, y, math.remainder(p1[2] - p0[2], math.tau)


def drive(k: int):
    """0.5 m/s ahead turning at 12°/s, then on the spot at 40°/s, then a stop."""
    if k <= 40:
        th = math.radians(1.2) * k
        r = 0.05 / math.radians(1.2)
        return -1.0 + r * math.sin(th), -1.0 + r * (1 - math.cos(th)), th
    x, y, th = drive(40)
    if k <= 55:
        return x, y, th + math.radians(4.0) * (k - 40)
    return x, y, th + math.radians(4.0) * 15


def test_a_moving_laser_s_poses_come_back_within_centimetres():
    odo = ScanOdometry(LaserOdometrySettings())
    start = drive(0)
    errors = []
    for k in range(70):
        truth = relative(start, drive(k))
        up = odo.update(room_scan(drive(k), k))
        assert up.status in ("keyframe", "matched")
        dist = math.hypot(up.pose[0] - truth[0], up.pose[1] - truth[1])
        errors.append((dist, abs(math.degrees(math.remainder(up.pose[2] - truth[2], math.tau)))))
    e = np.array(errors)
    assert e[:, 0].max() < 0.05 and e[:, 1].max() < 1.0, e[-5:]
    assert odo.counts["failed"] == 0 and odo.counts["refused"] == 0
    assert odo.counts["keyframes"] > 5  # it moved on from the first keyframe


def test_a_still_laser_with_noisy_scans_stays_still():
    odo = ScanOdometry(LaserOdometrySettings())
    poses = np.array([odo.update(room_scan((0.0, 0.0, 0.3), k, noise_m=0.02)).pose
                      for k in range(300)])  # fmt: skip
    assert np.abs(poses[:, :2]).max() < 0.02  # the matching noise of one scan ...
    assert np.degrees(np.abs(poses[:, 2])).max() < 0.3
    assert np.abs(poses[-50:, :2].mean(axis=0)).max() < 0.005  # ... that does not add up
    assert odo.counts["keyframes"] == 1  # matched against the first scan all along


def _bad(scan: LaserScan, value: float) -> LaserScan:
    r = np.full(len(scan.ranges_m()), value, dtype=np.float32)
    return LaserScan.from_ranges(
        r,
        stamp_ns=scan.stamp_ns,
        frame_id=scan.frame_id,
        angle_min_rad=scan.angle_min_rad,
        angle_increment_rad=scan.angle_increment_rad,
        range_min_m=scan.range_min_m,
        range_max_m=scan.range_max_m,
    )


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 0.0, 1e9])
def test_scans_without_returns_are_refused_and_counted_and_the_pose_carried_on(value):
    odo = ScanOdometry(LaserOdometrySettings(carry_twist_s=0.25))
    pose = lambda k: (0.05 * k, 0.0, 0.0)  # noqa: E731  0.5 m/s straight ahead
    for k in range(10):
        odo.update(room_scan(pose(k), k))
    x9 = odo.pose[0]
    for k in range(10, 15):  # 0.5 s without a usable scan
        up = odo.update(_bad(room_scan(pose(k), k), value))
        assert up.status == "refused"
    assert odo.counts["refused"] == 5
    # carried on at 0.5 m/s for carry_twist_s (2 scans), then held
    assert odo.pose[0] == pytest.approx(x9 + 0.1, abs=0.01)
    up = odo.update(room_scan(pose(15), 15))  # a new keyframe where the pose is
    assert up.status == "keyframe"
    for k in range(16, 20):
        up = odo.update(room_scan(pose(k), k))
        assert up.status == "matched"
    assert up.pose[0] - odo.pose[0] == 0.0 and up.pose[0] == pytest.approx(x9 + 0.1 + 0.2, abs=0.02)


def test_a_scan_of_somewhere_else_fails_the_match_and_is_counted():
    odo = ScanOdometry(LaserOdometrySettings(carry_twist_s=0.0))
    for k in range(5):
        odo.update(room_scan((0.0, 0.0, 0.0), k))
    a = np.radians(np.arange(0, 361, 10))  # a round room 1.2 m across, nothing like ROOM
    ring = [(0.6 * math.cos(u), 0.6 * math.sin(u), 0.6 * math.cos(v), 0.6 * math.sin(v))
            for u, v in itertools.pairwise(a)]  # fmt: skip
    elsewhere = make_scan([], ring, stamp_ns=5 * PERIOD_NS, fov_rad=math.radians(270))
    up = odo.update(elsewhere)
    assert up.status == "failed" and odo.counts["failed"] == 1
    assert up.pose == pytest.approx((0.0, 0.0, 0.0), abs=0.01)  # held (carry_twist_s 0)


def test_other_geometry_and_old_stamps_do_not_raise():
    odo = ScanOdometry(LaserOdometrySettings())
    for k in range(3):
        odo.update(room_scan((0.0, 0.0, 0.0), k))
    assert odo.update(room_scan((0.0, 0.0, 0.0), 1)).status == "refused"  # older stamp
    other = room_scan((0.0, 0.0, 0.0), 4, fov_rad=math.radians(180))
    assert odo.update(other).status == "keyframe" and odo.counts["resets"] == 1
    assert odo.update(room_scan((0.0, 0.0, 0.0), 5, fov_rad=math.radians(180))).status == "matched"
