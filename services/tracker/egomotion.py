"""Ego-motion: the robot's odometry pose at a scan's stamp, and the frame change between scans.

Odometry gives the robot's pose T = (t, theta) in the odometry frame. A point p0 in the base
frame at pose T0 is, in the base frame at pose T1,

    p1 = T1^-1 T0 p0 = R(theta0 - theta1) p0 + R(-theta1) (t0 - t1)        (``se2_change``)

Eq. 3-31 (thesis 3.6.2.3) as printed subtracts the odometry translation t1 - t0 without
rotating it into the new base frame (:func:`thesis_printed_transform`, kept for the test that
shows the difference). The pose at a scan's stamp is interpolated between the odometry
messages around it (linear in x, y, shortest-way in yaw), or extrapolated a little with the
last twist (:class:`OdometryBuffer`).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from followbot.schemas import Odometry
from followbot.services.common.geometry import Pose

from .estimators import wrap_angle

__all__ = ["OdometryBuffer", "thesis_printed_transform"]

_NS = 1_000_000_000


def thesis_printed_transform(points: np.ndarray, pose0: Pose, pose1: Pose) -> np.ndarray:
    """Eq. 3-31 exactly as printed (thesis p. 3.6.2.3), for comparison only: wrong whenever the
    robot both turns and moves, because the translation is not rotated into the new frame.

        d0 = |p0|, theta0 = atan2(y0, x0), theta_r = theta_r1 - theta_r0
        x1 = d0 cos(theta0 + theta_r) - (x_r1 - x_r0)
        y1 = d0 sin(theta0 + theta_r) - (y_r1 - y_r0)
    """
    p = np.asarray(points, dtype=float)
    d0 = np.hypot(p[:, 0], p[:, 1])
    a0 = np.arctan2(p[:, 1], p[:, 0])
    th_r = pose1[2] - pose0[2]
    return np.column_stack(
        [
            d0 * np.cos(a0 + th_r) - (pose1[0] - pose0[0]),
            d0 * np.sin(a0 + th_r) - (pose1[1] - pose0[1]),
        ]
    )


class OdometryBuffer:
    """Odometry poses by stamp; the pose at any stamp in range, interpolated.

    Out-of-order messages are inserted in order; the oldest are forgotten beyond ``capacity``.
    A stamp after the newest message is extrapolated along the last twist (an arc) for at most
    ``max_extrapolation_ns``; a stamp before the oldest has no pose.
    """

    def __init__(self, capacity: int = 4096, max_extrapolation_ns: int = 100_000_000) -> None:
        self.capacity = capacity
        self.max_extrapolation_ns = max_extrapolation_ns
        self._stamps: list[int] = []
        self._poses: list[tuple[float, float, float, float, float]] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, odom: Odometry) -> None:
        item = (odom.x_m, odom.y_m, odom.yaw_rad, odom.v_mps, odom.w_radps)
        stamps = self._stamps
        if not stamps or odom.stamp_ns > stamps[-1]:
            stamps.append(odom.stamp_ns)
            self._poses.append(item)
        else:
            i = bisect.bisect_left(stamps, odom.stamp_ns)
            if i < len(stamps) and stamps[i] == odom.stamp_ns:
                self._poses[i] = item
            else:
                stamps.insert(i, odom.stamp_ns)
                self._poses.insert(i, item)
        if len(stamps) > self.capacity:
            drop = len(stamps) - self.capacity // 2
            del stamps[:drop]
            del self._poses[:drop]

    def pose_at(self, stamp_ns: int) -> Pose | None:
        stamps = self._stamps
        if not stamps or stamp_ns < stamps[0]:
            return None
        if stamp_ns >= stamps[-1]:
            dt_ns = stamp_ns - stamps[-1]
            if dt_ns > self.max_extrapolation_ns:
                return None
            x, y, th, v, w = self._poses[-1]
            dt = dt_ns / _NS
            if abs(w) > 1e-9:
                x += v / w * (math.sin(th + w * dt) - math.sin(th))
                y -= v / w * (math.cos(th + w * dt) - math.cos(th))
            else:
                x += v * dt * math.cos(th)
                y += v * dt * math.sin(th)
            return (x, y, th + w * dt)
        i = bisect.bisect_right(stamps, stamp_ns)  # stamps[i-1] <= stamp < stamps[i]
        s0, s1 = stamps[i - 1], stamps[i]
        p0, p1 = self._poses[i - 1], self._poses[i]
        f = (stamp_ns - s0) / (s1 - s0)
        dth = float(wrap_angle(p1[2] - p0[2]))
        return (p0[0] + f * (p1[0] - p0[0]), p0[1] + f * (p1[1] - p0[1]), p0[2] + f * dth)
