"""CameraModel and depth decoding (REP-118)."""

from __future__ import annotations

import numpy as np
import pytest

from scanfuse import CameraModel, DepthEncodingError, InputError, decode_depth
from scanfuse.camera import depth_in_metres


def test_16uc1_little_endian_is_millimetres_without_copy():
    image = np.array([[1000, 0, 2500], [7, 65535, 1]], dtype='<u2')
    raw = image.tobytes()
    decoded = decode_depth(raw, '16UC1', 3, 2)
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, image)
    assert np.shares_memory(decoded, np.frombuffer(raw, np.uint8))


def test_16uc1_big_endian_is_swapped_to_native():
    image = np.array([[1000, 0, 2500]], dtype='>u2')
    decoded = decode_depth(image.tobytes(), '16UC1', 3, 1, is_bigendian=True)
    np.testing.assert_array_equal(decoded, [[1000, 0, 2500]])


def test_row_padding_is_skipped():
    # Two rows of two uint16 pixels, each row padded to 6 bytes with 0xEE.
    raw = bytes([0xE8, 0x03, 0xD0, 0x07, 0xEE, 0xEE, 0xB8, 0x0B, 0xA0, 0x0F, 0xEE, 0xEE])
    decoded = decode_depth(raw, '16UC1', 2, 2, step=6)
    np.testing.assert_array_equal(decoded, [[1000, 2000], [3000, 4000]])


def test_32fc1_is_metres():
    image = np.array([[1.5, np.nan], [np.inf, 0.25]], dtype='<f4')
    decoded = decode_depth(image.tobytes(), '32FC1', 2, 2)
    assert decoded.dtype == np.float32
    np.testing.assert_array_equal(decoded, image)


def test_depth_in_metres_turns_zero_millimetres_into_nan():
    metres = depth_in_metres(np.array([[1000, 0, 1]], dtype=np.uint16))
    assert metres[0, 0] == pytest.approx(1.0)
    assert np.isnan(metres[0, 1])
    assert metres[0, 2] == pytest.approx(0.001)


def test_unknown_encoding_names_the_supported_ones():
    with pytest.raises(DepthEncodingError, match=r"'rgb8' is not supported; use one of 16UC1"):
        decode_depth(b'\0' * 12, 'rgb8', 2, 2)


def test_truncated_buffer_is_rejected():
    with pytest.raises(DepthEncodingError, match=r'holds 6 bytes.*needs 8'):
        decode_depth(b'\0' * 6, '16UC1', 2, 2)


def test_step_shorter_than_a_row_is_rejected():
    with pytest.raises(DepthEncodingError, match='step 2 is shorter than a row'):
        decode_depth(b'\0' * 8, '16UC1', 2, 2, step=2)


def test_zero_size_is_rejected():
    with pytest.raises(DepthEncodingError, match='size must be positive'):
        decode_depth(b'', '16UC1', 0, 2)


def test_unsupported_depth_dtype_is_rejected():
    with pytest.raises(InputError, match='dtype int32 is not supported'):
        depth_in_metres(np.zeros((2, 2), dtype=np.int32))


def test_zero_focal_length_is_rejected():
    with pytest.raises(InputError, match=r'focal length fx=0\.0 must be positive'):
        CameraModel.from_intrinsics(640, 480, 0.0, 525.0, 320.0, 240.0)


def test_all_zero_camera_info_k_is_rejected():
    with pytest.raises(InputError, match='K is all zero'):
        CameraModel.from_camera_info(640, 480, [0.0] * 9)


def test_camera_info_k_must_have_nine_values():
    with pytest.raises(InputError, match='K must have 9 values, got 4'):
        CameraModel.from_camera_info(640, 480, [1.0, 0.0, 0.0, 1.0])


def test_from_camera_info_reads_row_major_k():
    camera = CameraModel.from_camera_info(
        640, 480, [525.0, 0.0, 320.0, 0.0, 526.0, 240.0, 0.0, 0.0, 1.0]
    )
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (525.0, 526.0, 320.0, 240.0)


def test_normalized_coordinates_follow_the_pinhole_model():
    camera = CameraModel.from_intrinsics(4, 3, 2.0, 4.0, 1.5, 1.0)
    x_n, y_n = camera.normalized_coordinates
    assert x_n.shape == (3, 4)
    # (u - cx) / fx and (v - cy) / fy, by hand.
    np.testing.assert_allclose(x_n[0], [-0.75, -0.25, 0.25, 0.75])
    np.testing.assert_allclose(y_n[:, 0], [-0.25, 0.0, 0.25])


@pytest.mark.parametrize(
    ('depth', 'match'),
    [
        (np.zeros((480, 640, 3), np.uint16), 'two-dimensional'),
        (np.zeros((480, 639), np.uint16), 'is 639x480 but the camera model is 640x480'),
        (np.zeros((480, 640), np.int16), 'dtype int16 is not supported'),
        (np.zeros((0, 0), np.uint16), 'is 0x0 but the camera model'),
    ],
)
def test_check_depth_rejects_bad_images(depth, match):
    camera = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)
    with pytest.raises(InputError, match=match):
        camera.check_depth(depth)
