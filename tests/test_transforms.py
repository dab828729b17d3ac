"""Rigid transforms and extrinsics: known rotations worked out by hand (REP-103)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanfuse.config import FusionConfig
from scanfuse.errors import TransformError
from scanfuse.transforms import BODY_TO_OPTICAL, Extrinsics, Transform

angles = st.floats(-math.pi, math.pi, allow_nan=False)
pitches = st.floats(-1.5, 1.5, allow_nan=False)
offsets = st.floats(-5.0, 5.0, allow_nan=False)
translations = st.tuples(offsets, offsets, offsets)


def transforms() -> st.SearchStrategy[Transform]:
    return st.builds(Transform.from_rpy, angles, pitches, angles, translations)


@pytest.mark.parametrize(
    ('rpy', 'axis', 'expected'),
    [
        # yaw +90 deg turns forward (x) into left (y)
        ((0.0, 0.0, math.pi / 2), (1, 0, 0), (0, 1, 0)),
        # pitch +90 deg turns forward into down: positive pitch looks down
        ((0.0, math.pi / 2, 0.0), (1, 0, 0), (0, 0, -1)),
        # roll +90 deg turns left (y) into up (z): the right side goes down
        ((math.pi / 2, 0.0, 0.0), (0, 1, 0), (0, 0, 1)),
        # roll first, then pitch, then yaw (fixed axes): Rx(90) y -> z, Ry(90) z -> x,
        # Rz(90) x -> y
        ((math.pi / 2, math.pi / 2, math.pi / 2), (0, 1, 0), (0, 1, 0)),
    ],
)
def test_from_rpy_known_rotations(rpy, axis, expected):
    transform = Transform.from_rpy(*rpy)
    np.testing.assert_allclose(transform.apply(axis), expected, atol=1e-12)


def test_quaternion_of_yaw_is_half_angle_about_z():
    # A rotation by theta about z is (0, 0, sin(theta/2), cos(theta/2)).
    transform = Transform.from_rpy(0.0, 0.0, 1.0)
    np.testing.assert_allclose(transform.rotation, (0.0, 0.0, math.sin(0.5), math.cos(0.5)))


def test_quaternion_is_normalised_and_sign_canonical():
    transform = Transform.from_quaternion((0.0, 0.0, -2.0, -2.0))
    half = math.sqrt(0.5)
    assert transform.rotation == pytest.approx((0.0, 0.0, half, half))
    assert transform == Transform.from_quaternion((0.0, 0.0, 1.0, 1.0))
    assert hash(transform) == hash(Transform.from_quaternion((0.0, 0.0, 1.0, 1.0)))


def test_translation_then_rotation():
    transform = Transform.from_rpy(0.0, 0.0, math.pi / 2, (1.0, 2.0, 3.0))
    # the child's x axis point (1, 0, 0) is rotated to (0, 1, 0) and shifted
    np.testing.assert_allclose(transform.apply([[1.0, 0.0, 0.0]]), [[1.0, 3.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(transform.matrix[:3, 3], (1.0, 2.0, 3.0))


@given(angles, pitches, angles)
def test_rpy_round_trip(roll, pitch, yaw):
    recovered = Transform.from_rpy(roll, pitch, yaw).rpy()
    again = Transform.from_rpy(*recovered)
    np.testing.assert_allclose(
        again.rotation_matrix, Transform.from_rpy(roll, pitch, yaw).rotation_matrix, atol=1e-9
    )
    assert recovered[1] == pytest.approx(pitch, abs=1e-6)


@given(transforms())
def test_quaternion_matrix_round_trip(transform):
    again = Transform.from_matrix(transform.matrix)
    np.testing.assert_allclose(again.rotation, transform.rotation, atol=1e-9)
    np.testing.assert_allclose(again.translation, transform.translation, atol=1e-9)
    rotation = transform.rotation_matrix
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)


@given(transforms(), st.lists(translations, min_size=1, max_size=5))
def test_inverse_undoes(transform, points):
    points = np.array(points)
    np.testing.assert_allclose(
        transform.inverse().apply(transform.apply(points)), points, atol=1e-9
    )
    identity = transform @ transform.inverse()
    np.testing.assert_allclose(identity.matrix, np.eye(4), atol=1e-9)


@given(transforms(), transforms(), st.lists(translations, min_size=1, max_size=5))
def test_compose_is_apply_after_apply(a, b, points):
    points = np.array(points)
    np.testing.assert_allclose((a @ b).apply(points), a.apply(b.apply(points)), atol=1e-9)
    np.testing.assert_allclose(a.compose(b).matrix, a.matrix @ b.matrix, atol=1e-9)


def test_body_to_optical_axes():
    # optical z (forward) is body x, optical x (right) is body -y, optical y (down) body -z
    np.testing.assert_allclose(BODY_TO_OPTICAL.apply((0, 0, 1)), (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(BODY_TO_OPTICAL.apply((1, 0, 0)), (0, -1, 0), atol=1e-12)
    np.testing.assert_allclose(BODY_TO_OPTICAL.apply((0, 1, 0)), (0, 0, -1), atol=1e-12)
    # the static transform ROS camera drivers publish: setRPY(-pi/2, 0, -pi/2)
    np.testing.assert_allclose(
        BODY_TO_OPTICAL.matrix,
        Transform.from_rpy(-math.pi / 2, 0.0, -math.pi / 2).matrix,
        atol=1e-12,
    )


def test_camera_pitched_down_90_deg_looks_at_the_floor():
    extrinsics = Extrinsics.from_mounting(camera_height=0.5, camera_pitch=math.pi / 2)
    camera = extrinsics.base_to_camera_optical
    # the optical axis points to base -z; the optical origin is 0.5 m above the floor
    np.testing.assert_allclose(camera.rotation_matrix @ (0, 0, 1), (0, 0, -1), atol=1e-12)
    np.testing.assert_allclose(camera.apply((0, 0, 0.5)), (0, 0, 0), atol=1e-12)
    # image down (optical y) is then base -x: the bottom of the image is behind
    np.testing.assert_allclose(camera.rotation_matrix @ (0, 1, 0), (-1, 0, 0), atol=1e-12)


def test_camera_pitched_20_deg_ray_meets_floor_where_trigonometry_says():
    pitch = math.radians(20.0)
    extrinsics = Extrinsics.from_mounting(camera_x=0.1, camera_height=0.4, camera_pitch=pitch)
    camera = extrinsics.base_to_camera_optical
    z = 0.4 / math.sin(pitch)  # depth along the optical axis to the floor
    np.testing.assert_allclose(
        camera.apply((0, 0, z)), (0.1 + 0.4 / math.tan(pitch), 0.0, 0.0), atol=1e-12
    )


def test_camera_yaw_left_and_roll_right_side_down():
    left = Extrinsics.from_mounting(camera_height=0.3, camera_yaw=math.pi / 2)
    np.testing.assert_allclose(
        left.base_to_camera_optical.rotation_matrix @ (0, 0, 1), (0, 1, 0), atol=1e-12
    )
    rolled = Extrinsics.from_mounting(camera_height=0.3, camera_roll=math.radians(30.0))
    right = rolled.base_to_camera_optical.rotation_matrix @ (1, 0, 0)
    np.testing.assert_allclose(right, (0, -math.cos(math.radians(30)), -0.5), atol=1e-12)


def test_laser_to_camera_optical_offsets():
    extrinsics = Extrinsics.from_mounting(
        camera_x=0.2, camera_y=0.05, camera_height=0.45, lidar_x=0.1, lidar_height=0.3
    )
    laser_to_camera = extrinsics.laser_to_camera_optical
    np.testing.assert_allclose(laser_to_camera.translation, (0.1, 0.05, 0.15), atol=1e-12)
    turned = Extrinsics.from_mounting(camera_height=0.45, lidar_x=-0.1, lidar_yaw=math.pi / 2)
    # the camera 0.1 m ahead of a LiDAR turned left by 90 deg is on the LiDAR's -y side
    np.testing.assert_allclose(
        turned.laser_to_camera_optical.translation[:2], (0.0, -0.1), atol=1e-12
    )


def test_from_config_uses_camera_and_lidar_fields():
    config = FusionConfig(
        camera_x=0.2,
        camera_y=-0.1,
        camera_height=0.5,
        camera_pitch=0.3,
        lidar_x=-0.05,
        lidar_height=0.25,
        lidar_yaw=0.1,
    )
    extrinsics = Extrinsics.from_config(config)
    assert extrinsics == Extrinsics.from_mounting(
        camera_x=0.2,
        camera_y=-0.1,
        camera_height=0.5,
        camera_pitch=0.3,
        lidar_x=-0.05,
        lidar_height=0.25,
        lidar_yaw=0.1,
    )
    assert extrinsics.base_to_camera_optical.translation == pytest.approx((0.2, -0.1, 0.5))
    assert extrinsics.base_to_laser.translation == pytest.approx((-0.05, 0.0, 0.25))
    assert extrinsics.base_to_laser.rpy()[2] == pytest.approx(0.1)
    assert {extrinsics: 1}[Extrinsics.from_config(config)] == 1


@pytest.mark.parametrize(
    ('build', 'match'),
    [
        (lambda: Transform.from_quaternion((0, 0, 0, 0)), 'zero length'),
        (lambda: Transform.from_quaternion((0, 0, 0, 1), (math.nan, 0, 0)), 'finite'),
        (lambda: Transform((0.0, 0.0, 1.0), (0.0, 0.0, 0.0)), '4-value quaternion'),  # type: ignore[arg-type]
        (lambda: Transform.from_matrix(np.eye(3)), '4x4 or 3x4'),
        (lambda: Transform.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0])), 'must be a rotation'),
        (lambda: Transform().apply(np.zeros((2, 2))), r'\(N, 3\)'),
    ],
)
def test_errors(build, match):
    with pytest.raises(TransformError, match=match):
        build()
