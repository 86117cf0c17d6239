"""Plane geometry the services share (REP-103: radians, counter-clockwise positive)."""

import math

import numpy as np

__all__ = ["Pose", "rotation", "se2_change", "transform_points", "wrap_angle"]

Pose = tuple[float, float, float]
"""(x, y, yaw): a base pose in an odometry or world frame."""


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi): a float for a Python float or int (numpy float64 is one),
    else an array."""
    if isinstance(a, float | int):
        return (a + math.pi) % math.tau - math.pi
    return (np.asarray(a) + np.pi) % math.tau - np.pi


def rotation(theta: float) -> np.ndarray:
    """The 2x2 matrix turning a vector by ``theta`` (counter-clockwise)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def se2_change(pose0: Pose, pose1: Pose) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with p1 = R p0 + t: base frame at odometry pose ``pose0`` -> at ``pose1``.

    R = R(theta0 - theta1), t = R(-theta1) (t0 - t1)  (p1 = T1^-1 T0 p0).
    """
    x0, y0, th0 = pose0
    x1, y1, th1 = pose1
    return rotation(th0 - th1), rotation(-th1) @ np.array([x0 - x1, y0 - y1])


def transform_points(points: np.ndarray, pose0: Pose, pose1: Pose) -> np.ndarray:
    """(n, 2) points in the base frame at ``pose0`` expressed in the base frame at ``pose1``."""
    r, t = se2_change(pose0, pose1)
    return np.asarray(points, dtype=float) @ r.T + t
