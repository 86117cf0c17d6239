"""The robot's odometry pose at any stamp: one buffer for every stage that compensates ego-motion.

Odometry messages give the base pose (x, y, yaw) in the odometry frame and the twist (v, w).
The pose at a stamp between two messages is interpolated: linear in x and y, the shortest way
round in yaw. A stamp after the newest message is extrapolated along the newest twist (an arc
of the unicycle model, a straight line when w is 0) for at most ``max_extrapolation_s``: in
lock-step the odometry of a tick may arrive after its scan. A stamp before the oldest message,
or too far past the newest, has no pose.

Messages may arrive out of order (two publishers, a late delivery): a late message is inserted
at its stamp, so the history stays sorted and complete; a message with a stamp already held
replaces it. A source whose clock restarted is the runtime's to detect (its clock guard calls
the stage's ``on_restart``); the stage then starts a fresh buffer.
"""

from __future__ import annotations

import bisect
import math

from followbot.schemas import Odometry

from .geometry import Pose, wrap_angle

__all__ = ["OdometryBuffer"]

_NS = 1_000_000_000


class OdometryBuffer:
    """Odometry poses by stamp; the pose at any stamp they cover.

    At most ``capacity`` messages are kept: past it, the older half is forgotten at once (one
    deletion per ``capacity // 2`` messages instead of one per message).
    """

    def __init__(self, capacity: int = 4096, max_extrapolation_s: float = 0.1) -> None:
        if capacity < 2:
            raise ValueError(f"capacity must be at least 2, got {capacity}")
        if not max_extrapolation_s >= 0:
            raise ValueError(f"max_extrapolation_s must be >= 0, got {max_extrapolation_s}")
        self.capacity = capacity
        self.max_extrapolation_s = max_extrapolation_s
        self._max_extrapolation_ns = int(max_extrapolation_s * _NS)
        self._stamps: list[int] = []
        self._poses: list[tuple[float, float, float, float, float]] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, odom: Odometry) -> None:
        """Hold ``odom`` at its stamp (in order, whenever it arrives)."""
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
        """(x, y, yaw) at ``stamp_ns``, or None when the buffer does not cover it."""
        stamps = self._stamps
        if not stamps or stamp_ns < stamps[0]:
            return None
        if stamp_ns >= stamps[-1]:
            dt_ns = stamp_ns - stamps[-1]
            if dt_ns > self._max_extrapolation_ns:
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
