"""services/common/geometry: the angle wrap the simulator, laser_legs and the tracker share."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from followbot.services.common.geometry import wrap_angle

angles = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)


@given(angles)
def test_a_wrapped_angle_lies_in_minus_pi_to_pi_and_points_the_same_way(a):
    w = wrap_angle(a)
    assert isinstance(w, float)
    assert -math.pi <= w < math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9)
    assert math.sin(w) == pytest.approx(math.sin(a), abs=1e-9)


@given(st.lists(angles, min_size=1, max_size=20))
def test_arrays_wrap_element_by_element_as_scalars_do(xs):
    assert np.array_equal(wrap_angle(np.array(xs)), np.array([wrap_angle(x) for x in xs]))


def test_the_ends_of_the_interval():
    assert wrap_angle(math.pi) == -math.pi  # [-pi, pi): pi itself is -pi
    assert wrap_angle(-math.pi) == -math.pi
    assert wrap_angle(3 * math.pi / 2) == -math.pi / 2
    assert wrap_angle(0) == 0.0
