"""Angle wrapping (pipeline.geometry): one implementation for every yaw difference of a symmetric shape."""
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pipeline.geometry import Primitive, wrap_angle, wrap_symmetric


def test_wrap_symmetric_of_a_box_brings_a_half_turn_to_zero():
    assert wrap_symmetric(np.pi, np.pi) == 0.0
    assert np.isclose(wrap_symmetric(np.pi + 0.1, np.pi), 0.1)
    np.testing.assert_allclose(wrap_symmetric(np.array([-0.1, 3.0, -3.0]), np.pi), [-0.1, 3.0 - np.pi, np.pi - 3.0])


def test_wrap_symmetric_keeps_the_shape_and_is_half_open():
    a = np.zeros((2, 3))
    assert wrap_symmetric(a, np.pi).shape == (2, 3)
    assert wrap_symmetric(-np.pi / 2, np.pi) == -np.pi / 2  # [-period/2, period/2)
    assert wrap_symmetric(np.pi / 2, np.pi) == -np.pi / 2


def test_a_cylinder_has_no_yaw_difference():
    np.testing.assert_array_equal(wrap_symmetric(np.array([0.3, -2.0, 7.0]), 0.0), np.zeros(3))


def test_wrap_angle_is_the_full_turn_case():
    a = np.linspace(-20.0, 20.0, 401)
    np.testing.assert_array_equal(wrap_angle(a), wrap_symmetric(a, 2.0 * np.pi))
    np.testing.assert_array_equal(wrap_angle(a), (a + np.pi) % (2.0 * np.pi) - np.pi)  # the same bits as before


@given(st.floats(-1e3, 1e3), st.sampled_from([np.pi, 2.0 * np.pi, np.pi / 2]))
def test_wrapped_difference_is_in_range_and_congruent(a, period):
    w = float(wrap_symmetric(a, period))
    assert -period / 2 <= w < period / 2 or np.isclose(w, period / 2)
    k = (a - w) / period
    assert abs(k - round(k)) < 1e-9 * max(1.0, abs(a))


def test_canonical_box_pose_uses_the_same_wrap():
    box = Primitive(kind="box", half=(0.08, 0.03), centre=np.zeros(2))
    pose = box.canonical(np.array([0.1, 0.2, 3.0]))
    assert -np.pi / 2 <= pose[2] < np.pi / 2
    assert pose[2] == float(wrap_symmetric(3.0, np.pi))
