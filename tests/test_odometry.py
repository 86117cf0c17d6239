"""services/common/odometry: the robot's pose at a scan's stamp, as laser_legs (criterion 3) and
the tracker (ego-motion) both read it."""

from __future__ import annotations

import math

import pytest

from followbot.schemas import Odometry
from followbot.services.common.odometry import OdometryBuffer

MS = 1_000_000


def odom(stamp_ns, x, y, yaw, v=0.0, w=0.0):
    return Odometry(stamp_ns=stamp_ns, x_m=x, y_m=y, yaw_rad=yaw, v_mps=v, w_radps=w)


def test_the_pose_is_interpolated_at_the_stamp_across_the_yaw_wrap():
    buf = OdometryBuffer()
    buf.add(odom(0, 0.0, 0.0, 3.1))
    buf.add(odom(100 * MS, 1.0, 2.0, -3.1))  # crossed +-pi: 0.083 rad of turn, not 6.2
    x, y, th = buf.pose_at(25 * MS)
    assert (x, y) == pytest.approx((0.25, 0.5))
    assert math.remainder(th - 3.1, 2 * math.pi) == pytest.approx((2 * math.pi - 6.2) / 4)


def test_past_the_newest_message_the_pose_follows_the_last_twist_for_a_while():
    buf = OdometryBuffer(max_extrapolation_s=0.2)
    buf.add(odom(0, 0.0, 0.0, 3.0))
    buf.add(odom(100 * MS, 1.0, 2.0, -3.0, v=1.0))
    x, y, _ = buf.pose_at(200 * MS)
    assert (x, y) == pytest.approx((1.0 + 0.1 * math.cos(-3.0), 2.0 + 0.1 * math.sin(-3.0)))
    assert buf.pose_at(400 * MS) is None  # too far ahead
    assert buf.pose_at(-1) is None  # before the first message
    assert OdometryBuffer().pose_at(0) is None


def test_turning_the_extrapolation_follows_the_arc():
    buf = OdometryBuffer(max_extrapolation_s=1.0)
    buf.add(odom(0, 0.0, 0.0, 0.0, v=1.0, w=math.pi))  # a half circle of radius 1/pi per second
    x, y, th = buf.pose_at(1000 * MS)
    assert (x, y, th) == pytest.approx((0.0, 2 / math.pi, math.pi), abs=1e-9)


def test_a_late_message_takes_its_place_and_the_history_before_it_stays():
    buf = OdometryBuffer(max_extrapolation_s=0.05)
    buf.add(odom(0, 0.0, 0.0, 0.0, v=1.0))
    buf.add(odom(200 * MS, 2.0, 0.0, 0.0, v=1.0))
    buf.add(odom(100 * MS, 0.5, 0.0, 0.0, v=1.0))  # late, and not on the straight line
    assert len(buf) == 3
    assert buf.pose_at(0)[0] == pytest.approx(0.0)
    assert buf.pose_at(50 * MS)[0] == pytest.approx(0.25)  # between 0 and the late one
    assert buf.pose_at(150 * MS)[0] == pytest.approx(1.25)  # between the late one and 200
    assert buf.pose_at(240 * MS)[0] == pytest.approx(2.04)  # the newest still extrapolates
    buf.add(odom(100 * MS, 1.0, 0.0, 0.0, v=1.0))  # the same stamp again replaces it
    assert len(buf) == 3
    assert buf.pose_at(50 * MS)[0] == pytest.approx(0.5)


def test_past_its_capacity_the_buffer_forgets_the_oldest_half():
    buf = OdometryBuffer(capacity=10)
    for k in range(11):
        buf.add(odom(k * 10 * MS, 0.1 * k, 0.0, 0.0))
    assert len(buf) == 5
    assert buf.pose_at(55 * MS) is None  # forgotten
    assert buf.pose_at(75 * MS)[0] == pytest.approx(0.75)


@pytest.mark.parametrize("kwargs", [{"capacity": 1}, {"max_extrapolation_s": -0.1}])
def test_a_bad_setting_is_refused_by_name(kwargs):
    (name,) = kwargs
    with pytest.raises(ValueError, match=name):
        OdometryBuffer(**kwargs)
