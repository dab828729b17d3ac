"""Pinhole camera model, per-pixel ray tables and depth decoding (REP-118)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, cast

import numpy as np

from scanfuse.errors import DepthEncodingError, InputError

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

# REP-118: 16UC1 is millimetres with 0 = no measurement, 32FC1 is metres with NaN.
DEPTH_ENCODINGS: dict[str, np.dtype[np.uint16] | np.dtype[np.float32]] = {
    '16UC1': np.dtype(np.uint16),
    'mono16': np.dtype(np.uint16),
    '32FC1': np.dtype(np.float32),
}
MILLIMETRE = 0.001
# Largest pinhole ray slope |x/z| at an image corner: 89.994 degrees off the optical axis.
# A CameraInfo past it (fx = 1e-300, cx = 1e30) is corrupt, and its rays would overflow
# the float32 ray tables to Inf.
MAX_RAY_SLOPE = 1.0e4
# The largest image a CameraInfo may describe: 16384 a side, 2^26 pixels (8K is 2^25).
MAX_IMAGE_SIDE = 16_384
MAX_PIXELS = 1 << 26


def decode_depth(
    raw: bytes | bytearray | memoryview | npt.NDArray[np.uint8],
    encoding: str,
    width: int,
    height: int,
    *,
    is_bigendian: bool = False,
    step: int | None = None,
) -> npt.NDArray[np.uint16] | npt.NDArray[np.float32]:
    """View a depth image buffer as a (height, width) array in native byte order.

    Returns uint16 millimetres for `16UC1`, float32 metres for `32FC1`. The pixel
    buffer is not copied when it is already in native byte order; row padding
    (`step` larger than `width * bytes_per_pixel`) is honoured.
    """
    dtype = DEPTH_ENCODINGS.get(encoding)
    if dtype is None:
        supported = ', '.join(sorted(DEPTH_ENCODINGS))
        msg = (
            f'depth encoding {encoding!r} is not supported; use one of {supported} '
            '(16UC1 millimetres or 32FC1 metres, REP-118)'
        )
        raise DepthEncodingError(msg)
    if width <= 0 or height <= 0:
        msg = f'depth image size must be positive, got {width}x{height}'
        raise DepthEncodingError(msg)
    row_bytes = width * dtype.itemsize
    step = row_bytes if step is None else step
    if step < row_bytes:
        msg = f'step {step} is shorter than a row of {width} {encoding} pixels ({row_bytes} bytes)'
        raise DepthEncodingError(msg)
    buffer = np.frombuffer(raw, dtype=np.uint8)
    needed = step * (height - 1) + row_bytes
    if buffer.size < needed:
        msg = (
            f'depth buffer holds {buffer.size} bytes, a {width}x{height} {encoding} image with '
            f'step {step} needs {needed}; the message is truncated or its size fields are wrong'
        )
        raise DepthEncodingError(msg)
    typed = dtype.newbyteorder('>' if is_bigendian else '<')
    image = np.ndarray(
        shape=(height, width),
        dtype=typed,
        buffer=buffer,
        strides=(step, dtype.itemsize),
    )
    if typed.byteorder not in ('=', '|') and typed != dtype:
        image = image.astype(dtype)  # big-endian on this machine: one swapped copy
    return cast('npt.NDArray[np.uint16] | npt.NDArray[np.float32]', image)


def depth_in_metres(depth: npt.NDArray[np.generic]) -> npt.NDArray[np.float32]:
    """float32 metres from uint16 millimetres (0 -> NaN) or float32/float64 metres."""
    if depth.dtype == np.uint16:
        metres: npt.NDArray[np.float32] = depth.astype(np.float32) * np.float32(MILLIMETRE)
        metres[depth == 0] = np.nan
        return metres
    if depth.dtype in (np.float32, np.float64):
        as_float: npt.NDArray[np.float32] = depth.astype(np.float32, copy=False)
        return as_float
    msg = (
        f'depth image dtype {depth.dtype} is not supported; pass uint16 millimetres '
        '(16UC1) or float32 metres (32FC1)'
    )
    raise InputError(msg)


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of a depth camera, as in `sensor_msgs/CameraInfo`.

    Pixel (u, v) with depth Z (along the optical axis, REP-118) is the point
    (x_n Z, y_n Z, Z) in the optical frame (z forward, x right, y down), where
    (x_n, y_n) are the undistorted normalized coordinates of the pixel.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = ''
    distortion: tuple[float, ...] = field(default=())
    frame_id: str = ''

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            msg = f'camera size must be positive, got {self.width}x{self.height}'
            raise InputError(msg)
        if max(self.width, self.height) > MAX_IMAGE_SIDE or self.width * self.height > MAX_PIXELS:
            # Tables of one value per pixel are built from these numbers alone, before any
            # image arrives: 100 000 x 100 000 would ask for 80 GB.
            msg = (
                f'camera size {self.width}x{self.height} is beyond any depth camera (at most '
                f'{MAX_IMAGE_SIDE} a side and {MAX_PIXELS} pixels); publish the real image size'
            )
            raise InputError(msg)
        for name in ('fx', 'fy'):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0.0:
                msg = (
                    f'camera focal length {name}={value} must be positive and finite; '
                    'is the CameraInfo calibrated (K not all zero)?'
                )
                raise InputError(msg)
        for name in ('cx', 'cy'):
            if not math.isfinite(getattr(self, name)):
                msg = f'camera principal point {name} must be finite'
                raise InputError(msg)
        slope = max(
            abs(self.cx) / self.fx,
            abs(self.width - 1 - self.cx) / self.fx,
            abs(self.cy) / self.fy,
            abs(self.height - 1 - self.cy) / self.fy,
        )
        if not slope <= MAX_RAY_SLOPE:
            msg = (
                f'camera intrinsics fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy} put '
                f'an image corner {math.degrees(math.atan(slope)):.4f} degrees off the optical '
                'axis, beyond any pinhole camera; publish the calibrated CameraInfo'
            )
            raise InputError(msg)
        if not all(math.isfinite(value) for value in self.distortion):
            # NaN would also make the model unequal to itself: a cache miss on every frame.
            msg = (
                f'camera distortion coefficients {self.distortion} must be finite; '
                'publish the calibrated CameraInfo (D all zero for rectified depth)'
            )
            raise InputError(msg)

    @classmethod
    def from_intrinsics(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        *,
        frame_id: str = '',
    ) -> CameraModel:
        return cls(width, height, float(fx), float(fy), float(cx), float(cy), frame_id=frame_id)

    @classmethod
    def from_camera_info(
        cls,
        width: int,
        height: int,
        K: Sequence[float],
        D: Sequence[float] = (),
        distortion_model: str = '',
        *,
        frame_id: str = '',
    ) -> CameraModel:
        """From the fields of `sensor_msgs/CameraInfo` (K row-major 3x3)."""
        k = [float(value) for value in K]
        if len(k) != 9:
            msg = f'CameraInfo K must have 9 values, got {len(k)}'
            raise InputError(msg)
        if not any(k):
            msg = 'CameraInfo K is all zero: the camera is not calibrated; publish its intrinsics'
            raise InputError(msg)
        return cls(
            width,
            height,
            k[0],
            k[4],
            k[2],
            k[5],
            distortion_model=distortion_model,
            distortion=tuple(float(value) for value in D),
            frame_id=frame_id,
        )

    @property
    def has_distortion(self) -> bool:
        return any(value != 0.0 for value in self.distortion)

    @cached_property
    def normalized_coordinates(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """(x_n, y_n) of every pixel, each shaped (height, width): the ray with z = 1.

        Computed once per camera; per-frame work is then one multiply by depth.
        """
        u = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        x_n, y_n = np.meshgrid(u, v)
        if self.has_distortion:
            from scanfuse.distortion import undistort_normalized  # noqa: PLC0415

            x_n, y_n = undistort_normalized(x_n, y_n, self.distortion_model, self.distortion)
        x_table: npt.NDArray[np.float32] = x_n.astype(np.float32)
        y_table: npt.NDArray[np.float32] = y_n.astype(np.float32)
        x_table.setflags(write=False)
        y_table.setflags(write=False)
        return x_table, y_table

    def check_depth(self, depth: npt.NDArray[np.generic]) -> None:
        """Raise InputError unless `depth` is a (height, width) uint16 or float image."""
        if depth.ndim != 2:
            msg = f'depth image must be two-dimensional (rows, columns), got shape {depth.shape}'
            raise InputError(msg)
        if depth.shape != (self.height, self.width):
            msg = (
                f'depth image is {depth.shape[1]}x{depth.shape[0]} but the camera model is '
                f'{self.width}x{self.height}; use the CameraInfo that belongs to this image'
            )
            raise InputError(msg)
        if depth.dtype not in (np.uint16, np.float32, np.float64):
            msg = (
                f'depth image dtype {depth.dtype} is not supported; pass uint16 millimetres '
                '(16UC1) or float32 metres (32FC1)'
            )
            raise InputError(msg)

    def decode_depth(
        self,
        raw: bytes | bytearray | memoryview | npt.NDArray[np.uint8],
        encoding: str,
        is_bigendian: bool = False,
        step: int | None = None,
    ) -> npt.NDArray[np.uint16] | npt.NDArray[np.float32]:
        """Decode a depth image buffer of this camera's size; see `decode_depth`."""
        return decode_depth(
            raw, encoding, self.width, self.height, is_bigendian=is_bigendian, step=step
        )
