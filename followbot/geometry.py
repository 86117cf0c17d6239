"""Plane geometry the services share (REP-103: radians, counter-clockwise positive)."""

import math

import numpy as np

__all__ = ["wrap_angle"]


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi): a float for a Python float or int (numpy float64 is one),
    else an array."""
    if isinstance(a, float | int):
        return (a + math.pi) % math.tau - math.pi
    return (np.asarray(a) + np.pi) % math.tau - np.pi
