"""Ego-motion: the robot's odometry pose at a scan's stamp, and the frame change between scans.

Odometry gives the robot's pose T = (t, theta) in the odometry frame. A point p0 in the base
frame at pose T0 is, in the base frame at pose T1,

    p1 = T1^-1 T0 p0 = R(theta0 - theta1) p0 + R(-theta1) (t0 - t1)        (``se2_change``)

Eq. 3-31 (thesis 3.6.2.3) as printed subtracts the odometry translation t1 - t0 without
rotating it into the new base frame (:func:`thesis_printed_transform`, kept for the test that
shows the difference). The pose at a scan's stamp comes from the odometry buffer every stage
shares (:class:`followbot.services.common.odometry.OdometryBuffer`).
"""

from __future__ import annotations

import numpy as np

from followbot.services.common.geometry import Pose

__all__ = ["thesis_printed_transform"]


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
