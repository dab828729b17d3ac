"""The compiled cloud kernel gives the reference's scan bit for bit, reading PointCloud2 bytes
where they lie.

The reference is the binning as it was before the kernel (`cloud._nearest_loop`, run as
plain Python, and the obstacle method's numpy pick: `points_scan(..., reference=True)`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.convert.cloud import _KERNEL, points_scan
from scanfuse.motion import IDENTITY_MOTION, PlanarMotion
from scanfuse.ros.messages import POINT_CLOUD, cloud_from_cdr, cloud_to_cdr, deserialize, serialize
from scanfuse.scan import AngleGrid
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.render import box_depth

pytestmark = pytest.mark.skipif(_KERNEL is None, reason='numba is not installed')

LASER = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, 0.3))
FULL_TURN = AngleGrid(-math.pi, 2.0 * math.pi / 1080, 1080)
# A camera 0.45 m up, 0.1 m ahead of the LiDAR, pitched 20 deg down (the benchmark's mount).
CAMERA_MOUNT = Transform.from_rpy(0.0, math.radians(20.0), 0.0, (0.1, 0.0, 0.45)) @ BODY_TO_OPTICAL
# A tilted, yawed sensor off the axis: every entry of the transform is non-zero.
ROTATED_MOUNT = Transform.from_rpy(0.3, -0.25, 2.2, (-0.2, 0.15, 0.6))
# Floor, a wall 2.8 m ahead, a low box, a chair leg and a table top above the slab.
ROOM = (
    (2.8, 3.0, -4.0, 4.0, 0.0, 2.5),
    (1.2, 1.5, -0.6, -0.2, 0.0, 0.12),
    (1.1, 1.125, 0.35, 0.375, 0.0, 0.45),
    (1.9, 2.7, 0.2, 1.2, 0.70, 0.72),
)
# (min_points, cluster_spread): the plain nearest, the configured default, the k-th.
ESTIMATES = ((1, math.inf), (16, 0.02), (4, math.inf))


def both(points, mount, *, grid=FULL_TURN, motion=IDENTITY_MOTION, k=16, spread=0.02, **limits):
    """(kernel ranges, reference ranges) of the same points."""
    settings = {
        'motion': motion,
        'min_height': 0.03,
        'max_height': 0.5,
        'range_min': 0.2,
        'range_max': 3.0,
        'min_points': k,
        'cluster_spread': spread,
        **limits,
    }
    kernel = points_scan(points, mount, LASER, grid, **settings)
    reference = points_scan(points, mount, LASER, grid, reference=True, **settings)
    return kernel.ranges, reference.ranges


def assert_same(kernel, reference):
    assert kernel.dtype == reference.dtype == np.float32
    np.testing.assert_array_equal(kernel, reference)  # NaN where NaN, every bit elsewhere


def room_cloud(width=212, height=120, seed=0):
    """The room seen by a D435-like camera (87 deg), organized (height x width x 3, optical
    frame), with sigma = 0.01 Z^2 depth noise and 3 % of the pixels NaN (no return)."""
    focal = (width / 2.0) / math.tan(math.radians(87.0) / 2.0)
    camera = CameraModel.from_intrinsics(
        width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0
    )
    rng = np.random.default_rng(seed)
    depth = box_depth(camera, CAMERA_MOUNT, ROOM)
    depth = depth + 0.01 * depth**2 * rng.standard_normal(depth.shape)
    depth[~np.isfinite(depth) | (rng.random(depth.shape) < 0.03)] = np.nan
    x_n, y_n = (np.asarray(c, dtype=np.float64) for c in camera.normalized_coordinates)
    return np.stack([x_n * depth, y_n * depth, depth], axis=-1)


def random_cloud(count, seed, dtype):
    """Points all around a sensor, many inside the slab and range limits, 5 % NaN."""
    rng = np.random.default_rng(seed)
    points = rng.uniform([-3.5, -3.5, -0.7], [3.5, 3.5, 0.4], (count, 3))
    rows = np.flatnonzero(rng.random(count) < 0.05)
    points[rows, rng.integers(0, 3, rows.size)] = np.nan
    return points.astype(dtype)


@pytest.mark.parametrize('dtype', ['f4', 'f8'])
@pytest.mark.parametrize(('k', 'spread'), ESTIMATES)
def test_the_room_as_an_organized_cloud_decodes_to_the_reference_scan(dtype, k, spread):
    organized = room_cloud()
    raw = cloud_to_cdr(organized, frame_id='camera', stamp_ns=1, dtype=dtype)
    points = cloud_from_cdr(raw).points
    kernel, reference = both(points, CAMERA_MOUNT, k=k, spread=spread)
    assert_same(kernel, reference)
    # The room's obstacles are in front: the wall (~2.7 m), the box (~1.2 m), the chair leg.
    assert 40 <= np.isfinite(kernel).sum() <= 300


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
@pytest.mark.parametrize(('k', 'spread'), ESTIMATES)
def test_random_clouds_with_nan_in_a_rotated_moving_frame_give_the_reference_scan(dtype, k, spread):
    points = random_cloud(20_000, seed=k, dtype=dtype)
    motion = PlanarMotion(cos=math.cos(0.1), sin=math.sin(0.1), tx=0.05, ty=-0.02)
    kernel, reference = both(points, ROTATED_MOUNT, motion=motion, k=k, spread=spread)
    assert_same(kernel, reference)
    assert np.isfinite(kernel).sum() > 100  # not vacuous: points all around reach many slots


def test_a_shuffled_unorganized_cloud_of_the_room_gives_the_reference_scan():
    organized = room_cloud(seed=1)
    points = organized.reshape(-1, 3)[np.random.default_rng(2).permutation(212 * 120)]
    decoded = cloud_from_cdr(cloud_to_cdr(points, frame_id='c', stamp_ns=1)).points
    assert_same(*both(decoded, CAMERA_MOUNT))


def test_a_partial_grid_wraps_and_clips_slots_as_the_reference_does():
    # 200 slots from +170 deg on: the wrap at +-180 deg and the grid's end both clip.
    grid = AngleGrid(math.radians(170.0), 2.0 * math.pi / 1080, 200)
    points = random_cloud(20_000, seed=5, dtype=np.float32)
    assert_same(*both(points, ROTATED_MOUNT, grid=grid, k=3, spread=math.inf))


def test_points_exactly_on_the_limits_are_kept_or_dropped_as_the_reference_does():
    # Heights 0.03 and 0.5 (slab edges) and ranges 0.2 and 3.0 (range limits), in the
    # base frame (sensor = base): the kernel tests the same closed intervals.
    points = np.array(
        [
            [1.0, 0.0, 0.03],
            [1.0, 0.5, 0.5],
            [0.0, 0.2, 0.2],
            [0.0, -3.0, 0.2],
            [0.0, 0.0, 0.2],  # on the LiDAR's axis: r = 0
            [-1.0, 1e-9, 0.2],  # at +-180 deg
        ]
    )
    kernel, reference = both(
        points, Transform.identity(), k=1, spread=math.inf, range_min=0.2, range_max=3.0
    )
    assert_same(kernel, reference)
    assert np.isfinite(kernel).sum() == 5


def test_unaligned_big_endian_and_unevenly_spaced_fields_give_the_reference_scan():
    points = random_cloud(5_000, seed=7, dtype=np.float32)
    kernel, reference = both(points, ROTATED_MOUNT)
    # 13-byte points starting at byte 1: every float is misaligned, read in place.
    buffer = np.zeros(5_000 * 13 + 1, dtype=np.uint8)
    unaligned = np.ndarray((5_000, 3), np.float32, buffer, 1, (13, 4))
    unaligned[:] = points
    assert not unaligned.flags.aligned
    assert_same(both(unaligned, ROTATED_MOUNT)[0], reference)
    assert_same(both(points.astype('>f4'), ROTATED_MOUNT)[0], reference)
    assert_same(kernel, reference)


def message_of(points, **changes):
    message = deserialize(cloud_to_cdr(points, frame_id='c', stamp_ns=1), POINT_CLOUD)
    return type(message)(**{**message.__dict__, **changes})


def test_a_decoded_cloud_is_a_view_of_the_message_bytes():
    points = random_cloud(100, seed=8, dtype=np.float32)
    raw = cloud_to_cdr(points, frame_id='c', stamp_ns=1)
    decoded = cloud_from_cdr(raw).points
    np.testing.assert_array_equal(decoded, points)
    assert decoded.strides == (16, 4)  # x, y, z, 4 bytes of padding
    assert decoded.base is not None  # a view, not a copy


def test_fields_out_of_order_and_padded_rows_decode_to_their_points():
    from scanfuse.ros.messages import typestore

    store = typestore()
    field = store.types['sensor_msgs/msg/PointField']
    # 16-byte points laid out as (y, z, padding, x): not one strided view, so copied.
    points = np.array([[1.0, 2.0, 3.0], [-4.0, 5.5, 0.25]], dtype=np.float32)
    data = np.zeros((2, 16), dtype=np.uint8)
    data[:, 0:4] = points[:, 1:2].view(np.uint8)
    data[:, 4:8] = points[:, 2:3].view(np.uint8)
    data[:, 12:16] = points[:, 0:1].view(np.uint8)
    fields = [
        field(name='x', offset=12, datatype=7, count=1),
        field(name='y', offset=0, datatype=7, count=1),
        field(name='z', offset=4, datatype=7, count=1),
    ]
    message = message_of(points, fields=fields, data=data.reshape(-1))
    np.testing.assert_array_equal(
        cloud_from_cdr(serialize(message, POINT_CLOUD, store)).points, points
    )
    # 2 x 1 organized, each row padded to 24 bytes: the padding is not read as points.
    padded = np.zeros((2, 24), dtype=np.uint8)
    padded[:, :16] = np.frombuffer(cloud_to_cdr_bytes(points), dtype=np.uint8).reshape(2, 16)
    padded[:, 16:] = 0xFF  # NaN bytes, were they read
    message = message_of(points, height=2, width=1, row_step=24, data=padded.reshape(-1))
    decoded = cloud_from_cdr(serialize(message, POINT_CLOUD, store)).points
    np.testing.assert_array_equal(decoded, points)


def cloud_to_cdr_bytes(points):
    """The data bytes cloud_to_cdr writes for N x 3 float32 points (4 bytes padding)."""
    data = np.zeros((len(points), 16), dtype=np.uint8)
    data[:, :12] = np.ascontiguousarray(points, dtype='<f4').view(np.uint8).reshape(-1, 12)
    return data.tobytes()


def test_an_empty_cloud_decodes_to_no_points_and_an_empty_scan():
    raw = cloud_to_cdr(np.zeros((0, 3)), frame_id='c', stamp_ns=1)
    decoded = cloud_from_cdr(raw).points
    assert decoded.shape == (0, 3)
    kernel, reference = both(decoded, CAMERA_MOUNT)
    assert_same(kernel, reference)
    assert np.isnan(kernel).all()


@pytest.mark.parametrize('count', [1, 2, 3, 511, 512, 513, 1025])
@pytest.mark.parametrize('layout', ['xyz f4', 'xyz f8', 'xyz+pad f4', 'xyz+pad f8'])
def test_every_point_of_a_packed_run_is_read_whatever_the_count(count, layout):
    # x, y, z the first 3 of every 3 or 4 values (one run, loaded with shuffles): the
    # first and last points and the block edges (512) are where a run could be misread.
    kind, width = layout.split()[1], 4 if 'pad' in layout else 3
    rng = np.random.default_rng(count)
    bearing, reach = rng.uniform(-math.pi, math.pi, count), rng.uniform(0.5, 2.5, count)
    in_base = np.stack([reach * np.cos(bearing), reach * np.sin(bearing)], axis=1)
    in_base = np.column_stack([in_base, rng.uniform(0.1, 0.4, count)])  # inside the slab
    points = ROTATED_MOUNT.inverse().apply(in_base).astype(kind)
    padded = np.full((count, width), np.nan, dtype=points.dtype)  # NaN padding: never a point
    padded[:, :3] = points
    view = padded[:, :3]
    assert view.strides == (width * points.itemsize, points.itemsize)
    # k = 1, every point kept: a point missed or misread changes its slot's range.
    kernel, reference = both(view, ROTATED_MOUNT, k=1, spread=math.inf)
    assert_same(kernel, reference)
    assert_same(both(points, ROTATED_MOUNT, k=1, spread=math.inf)[0], reference)
    if count <= 3:  # three bearings at random, three slots of 1080
        assert np.isfinite(kernel).sum() == count
