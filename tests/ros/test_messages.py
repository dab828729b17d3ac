"""ROS message conversion (through rosbags typestores) and the TF store."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from scanfuse import CameraModel, MessageError, Scan, TransformError
from scanfuse.frames import StampedTransform, TransformStore
from scanfuse.ros import messages as rm
from scanfuse.ros.messages import (
    Distro,
)
from scanfuse.transforms import Transform

STAMP = 1_700_000_123_456_789_012
DISTROS = [Distro.HUMBLE, Distro.JAZZY]


STORES = {Distro.HUMBLE: Stores.ROS2_HUMBLE, Distro.JAZZY: Stores.ROS2_JAZZY}


def _independent_store(distro: Distro):  # a typestore not shared with the code under test
    return get_typestore(STORES[distro])


def _laser_scan_msg(store, ranges, intensities=()):
    t = store.types
    return t['sensor_msgs/msg/LaserScan'](
        header=t['std_msgs/msg/Header'](
            stamp=t['builtin_interfaces/msg/Time'](sec=1_700_000_123, nanosec=456_789_012),
            frame_id='laser',
        ),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.5,
        time_increment=0.001,
        scan_time=0.1,
        range_min=0.1,
        range_max=8.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.asarray(intensities, dtype=np.float32),
    )


@pytest.mark.parametrize('distro', DISTROS)
def test_laser_scan_from_cdr_has_every_field(distro):
    store = _independent_store(distro)
    raw = store.serialize_cdr(
        _laser_scan_msg(store, [1.0, np.inf, np.nan, 2.5, 0.0], [1, 2, 3, 4, 5]),
        'sensor_msgs/msg/LaserScan',
    )
    scan = rm.scan_from_cdr(raw, rm.typestore(distro))
    assert scan.stamp_ns == STAMP
    assert scan.frame_id == 'laser'
    assert (scan.angle_min, scan.angle_max, scan.angle_increment) == (-1.0, 1.0, 0.5)
    assert scan.range_min == pytest.approx(0.1)
    assert scan.range_max == 8.0
    assert scan.time_increment == pytest.approx(0.001)
    assert scan.scan_time == pytest.approx(0.1)
    np.testing.assert_array_equal(scan.ranges, [1.0, np.inf, np.nan, 2.5, 0.0])
    assert scan.intensities is not None
    np.testing.assert_array_equal(scan.intensities, [1, 2, 3, 4, 5])


@pytest.mark.parametrize('distro', DISTROS)
def test_laser_scan_round_trip_is_byte_identical(distro):
    store = _independent_store(distro)
    raw = bytes(
        store.serialize_cdr(
            _laser_scan_msg(store, [0.5, 1.5, np.inf, -np.inf, 3.0]), 'sensor_msgs/msg/LaserScan'
        )
    )
    assert rm.scan_to_cdr(rm.scan_from_cdr(raw), rm.typestore(distro)) == raw


def test_scan_to_cdr_is_read_by_an_independent_typestore():
    scan = Scan(-0.5, 0.5, 0.25, 0.2, 9.0, np.array([1, 2, 3, 4, 5], np.float32), stamp_ns=STAMP)
    message = _independent_store(Distro.JAZZY).deserialize_cdr(
        rm.scan_to_cdr(scan), 'sensor_msgs/msg/LaserScan'
    )
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1_700_000_123, 456_789_012)
    np.testing.assert_array_equal(message.ranges, [1, 2, 3, 4, 5])
    assert message.intensities.size == 0


def test_unusable_laser_scan_is_a_message_error():
    store = _independent_store(Distro.HUMBLE)
    message = _laser_scan_msg(store, [1.0, 2.0])
    message.angle_increment = 0.0
    with pytest.raises(MessageError, match=r'LaserScan in frame .laser. is unusable.*non-zero'):
        rm.scan_from_msg(message)


def test_garbage_bytes_are_a_message_error():
    with pytest.raises(MessageError, match=r'cannot decode a sensor_msgs/msg/LaserScan'):
        rm.scan_from_cdr(b'\x00\x01\x00\x00\x07')


def test_ros1_laser_scan_converts_to_the_same_scan():
    noetic = get_typestore(Stores.ROS1_NOETIC)
    t = noetic.types
    message = t['sensor_msgs/msg/LaserScan'](
        header=t['std_msgs/msg/Header'](
            seq=7, stamp=t['builtin_interfaces/msg/Time'](sec=5, nanosec=6), frame_id='/laser'
        ),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=1.0,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=5.0,
        ranges=np.array([1.0, 2.0, 3.0], np.float32),
        intensities=np.array([], np.float32),
    )
    raw = noetic.serialize_ros1(message, 'sensor_msgs/msg/LaserScan')
    scan = rm.scan_from_cdr(rm.ros1_to_cdr(raw, 'sensor_msgs/msg/LaserScan'))
    assert scan.stamp_ns == 5 * 10**9 + 6
    assert scan.frame_id == '/laser'
    np.testing.assert_array_equal(scan.ranges, [1.0, 2.0, 3.0])


def test_bad_ros1_bytes_are_a_message_error():
    with pytest.raises(MessageError, match=r'cannot convert a ROS 1 sensor_msgs/msg/LaserScan'):
        rm.ros1_to_cdr(b'\x01\x02', 'sensor_msgs/msg/LaserScan')


# ---------------------------------------------------------------- Image


@pytest.mark.parametrize('distro', DISTROS)
def test_depth_16uc1_decodes_without_copy(distro):
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 250
    raw = rm.depth_to_cdr(depth, frame_id='cam', stamp_ns=STAMP, store=rm.typestore(distro))
    image = rm.depth_from_cdr(raw, rm.typestore(distro))
    np.testing.assert_array_equal(image.depth, depth)
    assert image.depth.dtype == np.uint16
    assert (image.width, image.height, image.encoding) == (4, 3, '16UC1')
    assert (image.frame_id, image.stamp_ns) == ('cam', STAMP)
    assert np.shares_memory(image.depth, np.frombuffer(raw, dtype=np.uint8))


def test_depth_32fc1_big_endian_with_row_padding():
    store = _independent_store(Distro.HUMBLE)
    t = store.types
    values = np.array([[1.5, np.nan], [2.25, 4.0]], dtype='>f4')
    padded = np.zeros((2, 12), dtype=np.uint8)  # 8 bytes of pixels + 4 bytes padding per row
    padded[:, :8] = values.view(np.uint8).reshape(2, 8)
    message = t['sensor_msgs/msg/Image'](
        header=t['std_msgs/msg/Header'](
            stamp=t['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='cam'
        ),
        height=2,
        width=2,
        encoding='32FC1',
        is_bigendian=1,
        step=12,
        data=padded.reshape(-1),
    )
    image = rm.depth_from_cdr(store.serialize_cdr(message, 'sensor_msgs/msg/Image'))
    np.testing.assert_array_equal(image.depth, [[1.5, np.nan], [2.25, 4.0]])


def test_colour_image_is_not_depth():
    store = _independent_store(Distro.HUMBLE)
    t = store.types
    message = t['sensor_msgs/msg/Image'](
        header=t['std_msgs/msg/Header'](
            stamp=t['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='cam'
        ),
        height=1,
        width=1,
        encoding='rgb8',
        is_bigendian=0,
        step=3,
        data=np.zeros(3, np.uint8),
    )
    with pytest.raises(MessageError, match=r"depth Image in frame 'cam'.*'rgb8' is not supported"):
        rm.depth_from_msg(message)
    assert not rm.is_depth_encoding('rgb8')
    assert rm.is_depth_encoding('16UC1')


def test_depth_to_msg_rejects_non_depth_arrays():
    with pytest.raises(MessageError, match=r'2-D uint16'):
        rm.depth_to_msg(np.zeros((2, 2), np.uint8), frame_id='c', stamp_ns=0)


# ---------------------------------------------------------------- CameraInfo


def _camera_info(store, *, width=640, height=480, k=(525, 0, 320, 0, 525, 240, 0, 0, 1)):
    t = store.types
    return t['sensor_msgs/msg/CameraInfo'](
        header=t['std_msgs/msg/Header'](
            stamp=t['builtin_interfaces/msg/Time'](sec=2, nanosec=0), frame_id='optical'
        ),
        height=height,
        width=width,
        distortion_model='plumb_bob',
        d=np.zeros(5),
        k=np.array(k, dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=t['sensor_msgs/msg/RegionOfInterest'](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


@pytest.mark.parametrize('distro', DISTROS)
def test_camera_info_to_camera_model(distro):
    store = _independent_store(distro)
    raw = store.serialize_cdr(_camera_info(store), 'sensor_msgs/msg/CameraInfo')
    camera = rm.camera_from_cdr(raw, rm.typestore(distro))
    assert (camera.width, camera.height) == (640, 480)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (525, 525, 320, 240)
    assert camera.frame_id == 'optical'


def test_camera_model_round_trips_through_camera_info():
    camera = CameraModel.from_intrinsics(848, 480, 421.5, 420.0, 424.2, 239.1, frame_id='o')
    assert rm.camera_from_cdr(rm.camera_to_cdr(camera, stamp_ns=STAMP)) == CameraModel(
        848, 480, 421.5, 420.0, 424.2, 239.1, 'plumb_bob', (0.0,) * 5, 'o'
    )


def test_all_zero_k_is_rejected():
    store = _independent_store(Distro.HUMBLE)
    with pytest.raises(MessageError, match=r'all-zero K.*not calibrated'):
        rm.camera_from_msg(_camera_info(store, k=(0,) * 9))


@pytest.mark.parametrize(('width', 'height'), [(0, 480), (640, 0), (0, 0)])
def test_zero_size_camera_info_is_rejected(width, height):
    store = _independent_store(Distro.HUMBLE)
    with pytest.raises(MessageError, match=f'has size {width}x{height}'):
        rm.camera_from_msg(_camera_info(store, width=width, height=height))


def test_negative_focal_length_is_a_message_error():
    store = _independent_store(Distro.HUMBLE)
    with pytest.raises(MessageError, match=r'unusable.*focal length'):
        rm.camera_from_msg(_camera_info(store, k=(-5, 0, 1, 0, 5, 1, 0, 0, 1)))


def test_depth_image_of_another_size_than_its_camera_info_is_rejected():
    image = rm.depth_from_cdr(
        rm.depth_to_cdr(np.zeros((480, 640), np.uint16), frame_id='o', stamp_ns=0)
    )
    rm.check_depth_matches_camera(image, CameraModel.from_intrinsics(640, 480, 1, 1, 0, 0))
    with pytest.raises(MessageError, match=r'is 640x480 but its CameraInfo says 320x240'):
        rm.check_depth_matches_camera(image, CameraModel.from_intrinsics(320, 240, 1, 1, 0, 0))


# ---------------------------------------------------------------- TF

SQRT_HALF = math.sqrt(0.5)
YAW_90 = (0.0, 0.0, SQRT_HALF, SQRT_HALF)


def test_tf_message_round_trip():
    transforms = [
        StampedTransform('base_link', 'laser', (0.1, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0), STAMP),
        StampedTransform('base_link', 'camera_link', (0.2, -0.1, 0.5), YAW_90, STAMP),
    ]
    decoded = rm.transforms_from_cdr(rm.tf_message_to_cdr(transforms))
    assert [(t.parent, t.child, t.stamp_ns) for t in decoded] == [
        ('base_link', 'laser', STAMP),
        ('base_link', 'camera_link', STAMP),
    ]
    np.testing.assert_allclose(decoded[1].rotation, YAW_90)
    np.testing.assert_allclose(decoded[1].translation, (0.2, -0.1, 0.5))


def test_tf_leading_slash_is_dropped():
    transforms = [StampedTransform('/base_link', '/laser', (0, 0, 0), (0, 0, 0, 1))]
    decoded = rm.transforms_from_cdr(rm.tf_message_to_cdr(transforms))
    assert (decoded[0].parent, decoded[0].child) == ('base_link', 'laser')


def test_non_unit_quaternion_is_rejected():
    transforms = [StampedTransform('base_link', 'laser', (0, 0, 0), (0, 0, 0, 2.0))]
    with pytest.raises(MessageError, match=r'norm 2\.0000; it must be a unit quaternion'):
        rm.transforms_from_cdr(rm.tf_message_to_cdr(transforms))


def _camera_tree() -> TransformStore:
    store = TransformStore()
    store.add(StampedTransform('base_link', 'laser', (0, 0, 0.3), (0, 0, 0, 1)), static=True)
    store.add(StampedTransform('base_link', 'camera_link', (0.1, 0, 0.45), YAW_90), static=True)
    store.add(
        StampedTransform('camera_link', 'camera_optical', (0, 0, 0), (-0.5, 0.5, -0.5, 0.5)),
        static=True,
    )
    return store


def _apply(matrix, point):
    return (matrix @ np.append(point, 1.0))[:3]


def test_lookup_walks_the_chain_through_parents():
    tree = _camera_tree()
    # The optical axis (z) of the camera is camera_link's x, which the 90 deg yaw turns to
    # base +y: one metre along it is base (0.1, 1, 0.45).
    np.testing.assert_allclose(
        _apply(tree.lookup('base_link', 'camera_optical'), (0, 0, 1)), (0.1, 1.0, 0.45), atol=1e-12
    )
    # Optical x (right) is camera_link -y, which is base +x after the yaw.
    np.testing.assert_allclose(
        _apply(tree.lookup('base_link', 'camera_optical'), (1, 0, 0)), (1.1, 0.0, 0.45), atol=1e-12
    )
    # Between siblings through the common parent: same point seen from the laser (0.3 m up).
    np.testing.assert_allclose(
        _apply(tree.lookup('laser', 'camera_optical'), (0, 0, 1)), (0.1, 1.0, 0.15), atol=1e-12
    )
    np.testing.assert_array_equal(tree.lookup('laser', 'laser'), np.eye(4))


def test_unknown_frame_lists_known_frames():
    known = 'base_link, camera_link, camera_optical, laser'
    with pytest.raises(TransformError, match=rf"'lidar' is not in the TF tree.*{known}"):
        _camera_tree().lookup('base_link', 'lidar')


def test_separate_trees_have_no_chain():
    tree = _camera_tree()
    tree.add(StampedTransform('odom', 'imu', (0, 0, 0), (0, 0, 0, 1)), static=True)
    with pytest.raises(TransformError, match=r"no TF chain from 'base_link' to 'imu'.*separate"):
        tree.lookup('base_link', 'imu')
    assert not tree.can_transform('base_link', 'imu')
    assert tree.can_transform('laser', 'camera_optical')


def test_a_transform_closing_a_loop_is_refused_and_the_tree_kept():
    tree = TransformStore()
    tree.add(StampedTransform('a', 'b', (0, 0, 0), (0, 0, 0, 1)), static=True)
    with pytest.raises(TransformError, match=r"'b' -> 'a' would close a loop"):
        tree.add(StampedTransform('b', 'a', (0, 0, 0), (0, 0, 0, 1)), static=True)
    assert tree.lookup('a', 'b')[0, 3] == 0.0


def test_frame_cannot_be_its_own_parent():
    with pytest.raises(TransformError, match=r'cannot be its own parent'):
        TransformStore().add(StampedTransform('a', '/a', (0, 0, 0), (0, 0, 0, 1)), static=True)


def test_static_wins_over_dynamic_and_the_latest_dynamic_is_kept():
    tree = TransformStore()
    assert tree.add(StampedTransform('base_link', 'laser', (1, 0, 0), (0, 0, 0, 1)), static=False)
    assert tree.add(StampedTransform('base_link', 'laser', (2, 0, 0), (0, 0, 0, 1)), static=False)
    assert tree.lookup('base_link', 'laser')[0, 3] == 2.0
    # The same pose again is no change (a cache built on it stays valid).
    assert not tree.add(
        StampedTransform('base_link', 'laser', (2, 0, 0), (0, 0, 0, 1)), static=False
    )
    assert tree.add(StampedTransform('base_link', 'laser', (3, 0, 0), (0, 0, 0, 1)), static=True)
    assert not tree.add(
        StampedTransform('base_link', 'laser', (4, 0, 0), (0, 0, 0, 1)), static=False
    )
    assert tree.lookup('base_link', 'laser')[0, 3] == 3.0


def test_chain_names_the_transforms_a_lookup_uses_and_roots_are_listed():
    tree = TransformStore()
    tree.add(StampedTransform('odom', 'base_link', (5, 0, 0), (0, 0, 0, 1)), static=False)
    tree.add(StampedTransform('base_link', 'laser', (1, 0, 0), (0, 0, 0, 1)), static=True)
    tree.add(StampedTransform('base_link', 'camera', (0, 1, 0), (0, 0, 0, 1)), static=True)
    tree.add(StampedTransform('mount', 'scanner', (0, 0, 1), (0, 0, 0, 1)), static=True)
    # base_link -> laser does not go through odom -> base_link: odometry leaves it valid.
    assert tree.chain('base_link', 'laser') == {'laser'}
    assert tree.chain('laser', 'camera') == {'laser', 'camera'}
    assert tree.roots() == ['mount', 'odom']
    assert tree.root_of('scanner') == 'mount'


unit_quaternions = (
    st.tuples(*[st.floats(-1, 1) for _ in range(4)])
    .filter(lambda q: math.sqrt(sum(v * v for v in q)) > 0.1)
    .map(lambda q: tuple(v / math.sqrt(sum(w * w for w in q)) for v in q))
)
translations = st.tuples(*[st.floats(-5, 5) for _ in range(3)])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(unit_quaternions, translations), min_size=1, max_size=5))
def test_lookup_there_and_back_is_identity(chain):
    tree = TransformStore()
    for index, (rotation, translation) in enumerate(chain):
        tree.add(StampedTransform(f'f{index}', f'f{index + 1}', translation, rotation), static=True)
    there = tree.lookup('f0', f'f{len(chain)}')
    back = tree.lookup(f'f{len(chain)}', 'f0')
    np.testing.assert_allclose(there @ back, np.eye(4), atol=1e-9)
    rotation = there[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)


def test_quaternion_matrix_of_a_quarter_turn_about_z():
    np.testing.assert_allclose(
        Transform.from_quaternion(YAW_90).rotation_matrix,
        [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
        atol=1e-12,
    )
