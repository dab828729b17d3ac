"""Inverting lens distortion; the forward model is written here from OpenCV's documented formula."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanfuse.camera import CameraModel
from scanfuse.distortion import undistort_normalized
from scanfuse.errors import InputError

# A Kinect-like plumb_bob and a wide-angle rational_polynomial calibration.
PLUMB_BOB = (0.2, -0.45, 0.0015, -0.002, 0.25)
RATIONAL = (0.6, -0.1, 0.001, -0.0008, 0.01, 0.9, 0.02, 0.005)


def forward(x, y, k1, k2, p1, p2, k3, k4=0.0, k5=0.0, k6=0.0):
    """OpenCV's distortion: x' = x (1 + k1 r2 + k2 r4 + k3 r6) / (1 + k4 r2 + k5 r4 + k6 r6)
    + 2 p1 x y + p2 (r2 + 2 x2), y' = y (...) + p1 (r2 + 2 y2) + 2 p2 x y."""
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    return (
        x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
        y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
    )


# The field of view of a 640x480 camera with fx = fy = 525: |x| <= 0.61, |y| <= 0.46.
coordinates = st.floats(-0.6, 0.6, allow_nan=False)


@pytest.mark.parametrize(
    ('model', 'coeffs'), [('plumb_bob', PLUMB_BOB), ('rational_polynomial', RATIONAL)]
)
@given(x=coordinates, y=st.floats(-0.46, 0.46, allow_nan=False))
def test_undistort_inverts_the_forward_model(model, coeffs, x, y):
    x_d, y_d = forward(x, y, *coeffs)
    x_u, y_u = undistort_normalized(np.array([x_d]), np.array([y_d]), model, coeffs)
    assert x_u[0] == pytest.approx(x, abs=1e-6)
    assert y_u[0] == pytest.approx(y, abs=1e-6)


def test_undistort_grid_of_points():
    x, y = np.meshgrid(np.linspace(-0.6, 0.6, 41), np.linspace(-0.45, 0.45, 31))
    x_d, y_d = forward(x, y, *PLUMB_BOB)
    x_u, y_u = undistort_normalized(x_d, y_d, 'plumb_bob', PLUMB_BOB)
    assert np.abs(x_u - x).max() < 1e-6
    assert np.abs(y_u - y).max() < 1e-6


def test_zero_coefficients_change_nothing():
    x = np.array([0.3, -0.2])
    y = np.array([0.1, 0.4])
    x_u, y_u = undistort_normalized(x, y, 'plumb_bob', (0.0,) * 5)
    np.testing.assert_array_equal(x_u, x)
    np.testing.assert_array_equal(y_u, y)


def test_short_coefficient_list_means_zeros():
    x_d, y_d = forward(0.3, 0.2, 0.1, 0.0, 0.0, 0.0, 0.0)
    x_u, y_u = undistort_normalized(np.array([x_d]), np.array([y_d]), 'plumb_bob', (0.1,))
    assert (x_u[0], y_u[0]) == pytest.approx((0.3, 0.2), abs=1e-9)


def test_camera_rays_use_the_inverse():
    camera = CameraModel.from_camera_info(
        640, 480, (525.0, 0, 320.0, 0, 525.0, 240.0, 0, 0, 1), PLUMB_BOB, 'plumb_bob'
    )
    x_n, y_n = camera.normalized_coordinates
    # distorting each pixel's ray must land on the pixel it belongs to
    x_d, y_d = forward(x_n.astype(np.float64), y_n.astype(np.float64), *PLUMB_BOB)
    u = x_d * 525.0 + 320.0
    v = y_d * 525.0 + 240.0
    columns, rows = np.meshgrid(np.arange(640), np.arange(480))
    assert np.abs(u - columns).max() < 1e-3  # float32 rays: about 1e-7 * 525
    assert np.abs(v - rows).max() < 1e-3


def test_points_the_model_cannot_invert_are_nan():
    # k1 = -1 folds the image back on itself beyond r = 0.58: x_d = 2 has no preimage
    x_u, y_u = undistort_normalized(
        np.array([2.0, 0.1]), np.array([0.0, 0.0]), 'plumb_bob', (-1.0,)
    )
    assert np.isnan(x_u[0])
    assert np.isnan(y_u[0])
    # the point inside the fold is still inverted exactly
    assert forward(x_u[1], 0.0, -1.0, 0.0, 0.0, 0.0, 0.0)[0] == pytest.approx(0.1, abs=1e-9)


@pytest.mark.parametrize(
    ('model', 'coeffs', 'match'),
    [
        ('equidistant', (0.1, 0.0, 0.0, 0.0), 'not supported'),
        ('plumb_bob', (0.1, 0.0, 0.0, 0.0, 0.0, 0.3), 'non-zero extra terms'),
    ],
)
def test_errors(model, coeffs, match):
    with pytest.raises(InputError, match=match):
        undistort_normalized(np.zeros(1), np.zeros(1), model, coeffs)
