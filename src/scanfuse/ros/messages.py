"""`sensor_msgs` and `tf2_msgs` messages <-> scanfuse core types, through rosbags typestores.

CDR bytes in, CDR bytes out: (de)serialization is always done by rosbags for the
ROS 2 distribution chosen (Humble or Jazzy); nothing here reads or writes CDR by
hand. ROS 1 messages are converted to ROS 2 CDR with the typestore's
`ros1_to_cdr`, which drops the ROS 1 header's `seq`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from scanfuse.camera import DEPTH_ENCODINGS, CameraModel, decode_depth
from scanfuse.errors import InputError, MessageError
from scanfuse.frames import StampedTransform, frame_name
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan, check_scan_limits
from scanfuse.transforms import MAX_TRANSLATION

if TYPE_CHECKING:
    import numpy.typing as npt
    from rosbags.typesys.store import Typestore

    RawMessage = bytes | memoryview

LASER_SCAN = 'sensor_msgs/msg/LaserScan'
IMAGE = 'sensor_msgs/msg/Image'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
TF_MESSAGE = 'tf2_msgs/msg/TFMessage'
TRANSFORM_STAMPED = 'geometry_msgs/msg/TransformStamped'
ODOMETRY = 'nav_msgs/msg/Odometry'
IMU = 'sensor_msgs/msg/Imu'
NANOSECONDS = 1_000_000_000


class Distro(str, Enum):
    """ROS 2 distributions whose message definitions scanfuse reads and writes."""

    HUMBLE = 'humble'
    JAZZY = 'jazzy'


_STORES = {Distro.HUMBLE: Stores.ROS2_HUMBLE, Distro.JAZZY: Stores.ROS2_JAZZY}


@cache
def typestore(distro: Distro = Distro.HUMBLE) -> Typestore:
    """The rosbags typestore of `distro` (built once; typestores are immutable in use)."""
    return get_typestore(_STORES[Distro(distro)])


@dataclass(frozen=True)
class DepthImage:
    """A depth `sensor_msgs/Image`: pixels (a view of the message buffer), stamp and frame."""

    depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32]
    encoding: str
    frame_id: str
    stamp_ns: int

    @property
    def width(self) -> int:
        return int(self.depth.shape[1])

    @property
    def height(self) -> int:
        return int(self.depth.shape[0])


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a `builtin_interfaces/Time`."""
    return int(stamp.sec) * NANOSECONDS + int(stamp.nanosec)


def _time(store: Typestore, stamp_ns: int) -> Any:
    sec, nanosec = divmod(int(stamp_ns), NANOSECONDS)
    return store.types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)


def _header(store: Typestore, stamp_ns: int, frame_id: str) -> Any:
    return store.types['std_msgs/msg/Header'](stamp=_time(store, stamp_ns), frame_id=frame_id)


def deserialize(raw: RawMessage, msgtype: str, store: Typestore | None = None) -> Any:
    """A message object from CDR bytes; MessageError when the bytes are not a `msgtype`."""
    store = store or typestore()
    try:
        # A memoryview makes rosbags return arrays that view the buffer (bytes would be sliced).
        return store.deserialize_cdr(memoryview(raw), msgtype)
    except (SerdeError, ValueError, IndexError) as err:
        msg = (
            f'cannot decode a {msgtype} from {len(raw)} CDR bytes ({err}); is the topic type right?'
        )
        raise MessageError(msg) from err


def serialize(message: Any, msgtype: str, store: Typestore | None = None) -> bytes:
    """CDR bytes (little endian) of a message object."""
    store = store or typestore()
    return bytes(store.serialize_cdr(message, msgtype))


def ros1_to_cdr(raw: RawMessage, msgtype: str, store: Typestore | None = None) -> bytes:
    """ROS 2 CDR bytes of a ROS 1 serialized message of a type the typestore knows."""
    store = store or typestore()
    try:
        return bytes(store.ros1_to_cdr(raw, msgtype))
    except (SerdeError, ValueError, KeyError) as err:
        msg = f'cannot convert a ROS 1 {msgtype} to ROS 2 ({err})'
        raise MessageError(msg) from err


# ---------------------------------------------------------------- LaserScan


def scan_from_msg(message: Any) -> Scan:
    """`Scan` from a `sensor_msgs/LaserScan` object (ranges are not copied)."""
    intensities = np.asarray(message.intensities, dtype=np.float32)
    try:
        scan = Scan(
            angle_min=float(message.angle_min),
            angle_max=float(message.angle_max),
            angle_increment=float(message.angle_increment),
            range_min=float(message.range_min),
            range_max=float(message.range_max),
            ranges=np.asarray(message.ranges, dtype=np.float32),
            time_increment=float(message.time_increment),
            scan_time=float(message.scan_time),
            intensities=intensities if intensities.size else None,
            frame_id=str(message.header.frame_id),
            stamp_ns=stamp_to_ns(message.header.stamp),
        )
        check_scan_limits(scan)
    except InputError as err:
        msg = f'LaserScan in frame {message.header.frame_id!r} is unusable: {err}'
        raise MessageError(msg) from err
    return scan


def scan_to_msg(scan: Scan, store: Typestore | None = None) -> Any:
    """A `sensor_msgs/LaserScan` object holding `scan`."""
    store = store or typestore()
    intensities = np.empty(0, dtype=np.float32) if scan.intensities is None else scan.intensities
    return store.types[LASER_SCAN](
        header=_header(store, scan.stamp_ns, scan.frame_id),
        angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_max),
        angle_increment=float(scan.angle_increment),
        time_increment=float(scan.time_increment),
        scan_time=float(scan.scan_time),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=np.ascontiguousarray(scan.ranges, dtype=np.float32),
        intensities=np.ascontiguousarray(intensities, dtype=np.float32),
    )


def scan_from_cdr(raw: RawMessage, store: Typestore | None = None) -> Scan:
    return scan_from_msg(deserialize(raw, LASER_SCAN, store))


def scan_to_cdr(scan: Scan, store: Typestore | None = None) -> bytes:
    store = store or typestore()
    return serialize(scan_to_msg(scan, store), LASER_SCAN, store)


# ---------------------------------------------------------------- Image


def depth_from_msg(message: Any) -> DepthImage:
    """`DepthImage` from a `sensor_msgs/Image` (16UC1 or 32FC1); the pixels are not copied."""
    try:
        depth = decode_depth(
            message.data,
            str(message.encoding),
            int(message.width),
            int(message.height),
            is_bigendian=bool(message.is_bigendian),
            step=int(message.step),
        )
    except InputError as err:
        msg = f'depth Image in frame {message.header.frame_id!r} is unusable: {err}'
        raise MessageError(msg) from err
    return DepthImage(
        depth=depth,
        encoding=str(message.encoding),
        frame_id=str(message.header.frame_id),
        stamp_ns=stamp_to_ns(message.header.stamp),
    )


def depth_to_msg(
    depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32],
    *,
    frame_id: str,
    stamp_ns: int,
    store: Typestore | None = None,
) -> Any:
    """A `sensor_msgs/Image` of a uint16 (16UC1, mm) or float32 (32FC1, m) depth image."""
    store = store or typestore()
    encoding = {np.dtype(np.uint16): '16UC1', np.dtype(np.float32): '32FC1'}.get(depth.dtype)
    if encoding is None or depth.ndim != 2:
        msg = (
            f'a depth Image needs a 2-D uint16 (mm) or float32 (m) array, '
            f'got {depth.dtype} with shape {depth.shape}'
        )
        raise MessageError(msg)
    pixels = np.ascontiguousarray(depth, dtype=depth.dtype.newbyteorder('<'))
    height, width = pixels.shape
    return store.types[IMAGE](
        header=_header(store, stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * pixels.itemsize,
        data=pixels.view(np.uint8).reshape(-1),
    )


def depth_from_cdr(raw: RawMessage, store: Typestore | None = None) -> DepthImage:
    return depth_from_msg(deserialize(raw, IMAGE, store))


def depth_to_cdr(
    depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32],
    *,
    frame_id: str,
    stamp_ns: int,
    store: Typestore | None = None,
) -> bytes:
    store = store or typestore()
    message = depth_to_msg(depth, frame_id=frame_id, stamp_ns=stamp_ns, store=store)
    return serialize(message, IMAGE, store)


def is_depth_encoding(encoding: str) -> bool:
    """True for the depth encodings scanfuse decodes (REP-118)."""
    return encoding in DEPTH_ENCODINGS


# ---------------------------------------------------------------- CameraInfo


def camera_from_msg(message: Any) -> CameraModel:
    """`CameraModel` from a `sensor_msgs/CameraInfo`; MessageError when it is uncalibrated."""
    width, height = int(message.width), int(message.height)
    frame = message.header.frame_id
    if width <= 0 or height <= 0:
        msg = (
            f'CameraInfo in frame {frame!r} has size {width}x{height}; '
            'the camera driver must publish the image size'
        )
        raise MessageError(msg)
    k = [float(value) for value in message.k]
    if not any(k):
        msg = (
            f'CameraInfo in frame {frame!r} has an all-zero K: the camera is not calibrated; '
            'publish its intrinsics (fx, fy, cx, cy)'
        )
        raise MessageError(msg)
    try:
        return CameraModel.from_camera_info(
            width,
            height,
            k,
            [float(value) for value in message.d],
            str(message.distortion_model),
            frame_id=str(frame),
        )
    except InputError as err:
        msg = f'CameraInfo in frame {frame!r} is unusable: {err}'
        raise MessageError(msg) from err


def camera_to_msg(camera: CameraModel, *, stamp_ns: int, store: Typestore | None = None) -> Any:
    """A `sensor_msgs/CameraInfo` of a pinhole camera (P = [K | 0], R = identity)."""
    store = store or typestore()
    k = np.array(
        [camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0], dtype=np.float64
    )
    p = np.array(
        [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        dtype=np.float64,
    )
    roi = store.types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return store.types[CAMERA_INFO](
        header=_header(store, stamp_ns, camera.frame_id),
        height=camera.height,
        width=camera.width,
        distortion_model=camera.distortion_model or 'plumb_bob',
        d=np.array(camera.distortion or (0.0,) * 5, dtype=np.float64),
        k=k,
        r=np.eye(3, dtype=np.float64).reshape(-1),
        p=p,
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def camera_from_cdr(raw: RawMessage, store: Typestore | None = None) -> CameraModel:
    return camera_from_msg(deserialize(raw, CAMERA_INFO, store))


def camera_to_cdr(camera: CameraModel, *, stamp_ns: int, store: Typestore | None = None) -> bytes:
    store = store or typestore()
    return serialize(camera_to_msg(camera, stamp_ns=stamp_ns, store=store), CAMERA_INFO, store)


def check_depth_matches_camera(image: DepthImage, camera: CameraModel) -> None:
    """MessageError unless the depth Image has the size its CameraInfo states."""
    if (image.width, image.height) != (camera.width, camera.height):
        msg = (
            f'depth Image in frame {image.frame_id!r} is {image.width}x{image.height} but its '
            f'CameraInfo says {camera.width}x{camera.height}; record the CameraInfo that '
            'belongs to this image stream'
        )
        raise MessageError(msg)


# ---------------------------------------------------------------- TF


def transforms_from_msg(message: Any) -> list[StampedTransform]:
    """The transforms of a `tf2_msgs/TFMessage`."""
    out = []
    for stamped in message.transforms:
        t = stamped.transform.translation
        q = stamped.transform.rotation
        rotation = (float(q.x), float(q.y), float(q.z), float(q.w))
        norm = float(np.linalg.norm(rotation))
        if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            msg = (
                f'transform {stamped.header.frame_id!r} -> {stamped.child_frame_id!r} has a '
                f'rotation quaternion of norm {norm:.4f}; it must be a unit quaternion'
            )
            raise MessageError(msg)
        translation = (float(t.x), float(t.y), float(t.z))
        if not all(abs(value) <= MAX_TRANSLATION for value in translation):
            # Also false for NaN. A finite float64 past float32's range (1e39) would become
            # Inf in the conversions' float32 arithmetic.
            msg = (
                f'transform {stamped.header.frame_id!r} -> {stamped.child_frame_id!r} has the '
                f'translation {translation}; it must be finite and within {MAX_TRANSLATION:g} m'
            )
            raise MessageError(msg)
        out.append(
            StampedTransform(
                parent=frame_name(str(stamped.header.frame_id)),
                child=frame_name(str(stamped.child_frame_id)),
                translation=translation,
                rotation=tuple(value / norm for value in rotation),  # type: ignore[arg-type]
                stamp_ns=stamp_to_ns(stamped.header.stamp),
            )
        )
    return out


def tf_message_to_msg(transforms: list[StampedTransform], store: Typestore | None = None) -> Any:
    """A `tf2_msgs/TFMessage` holding `transforms`."""
    store = store or typestore()
    vector = store.types['geometry_msgs/msg/Vector3']
    quaternion = store.types['geometry_msgs/msg/Quaternion']
    transform = store.types['geometry_msgs/msg/Transform']
    stamped_type = store.types[TRANSFORM_STAMPED]
    stamped = [
        stamped_type(
            header=_header(store, item.stamp_ns, item.parent),
            child_frame_id=item.child,
            transform=transform(
                translation=vector(*item.translation),
                rotation=quaternion(*item.rotation),
            ),
        )
        for item in transforms
    ]
    return store.types[TF_MESSAGE](transforms=stamped)


def transforms_from_cdr(raw: RawMessage, store: Typestore | None = None) -> list[StampedTransform]:
    return transforms_from_msg(deserialize(raw, TF_MESSAGE, store))


def tf_message_to_cdr(transforms: list[StampedTransform], store: Typestore | None = None) -> bytes:
    store = store or typestore()
    return serialize(tf_message_to_msg(transforms, store), TF_MESSAGE, store)


@dataclass(frozen=True)
class OdometrySample:
    """A `nav_msgs/Odometry` reduced to what fusion needs: the planar pose of the base."""

    stamp_ns: int
    frame_id: str  # the odometry frame (odom)
    child_frame_id: str  # the base frame
    pose: PlanarPose


def odometry_from_msg(message: Any) -> OdometrySample:
    """The planar pose (x, y, yaw) of a `nav_msgs/Odometry`."""
    position = message.pose.pose.position
    q = message.pose.pose.orientation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    values = (float(position.x), float(position.y), x, y, z, w)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not all(math.isfinite(v) for v in values) or abs(norm - 1.0) > 1e-3:
        msg = (
            f'Odometry in frame {message.header.frame_id!r} has position '
            f'({values[0]}, {values[1]}) and an orientation of norm {norm:.4f}: it needs finite '
            'values and a unit quaternion'
        )
        raise MessageError(msg)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return OdometrySample(
        stamp_to_ns(message.header.stamp),
        frame_name(str(message.header.frame_id)),
        frame_name(str(message.child_frame_id)),
        PlanarPose(values[0], values[1], yaw),
    )


@dataclass(frozen=True)
class ImuOrientation:
    """A `sensor_msgs/Imu` reduced to what fusion needs: its frame's attitude (x, y, z, w).

    The quaternion is passed on as it came: `FusionStream.add_imu` refuses (and counts) one
    that is no unit quaternion, as REP-145's "no orientation" (all zero) is not.
    """

    stamp_ns: int
    frame_id: str
    orientation: tuple[float, float, float, float]


def imu_from_msg(message: Any) -> ImuOrientation:
    q = message.orientation
    return ImuOrientation(
        stamp_to_ns(message.header.stamp),
        frame_name(str(message.header.frame_id)),
        (float(q.x), float(q.y), float(q.z), float(q.w)),
    )


def imu_from_cdr(raw: RawMessage, store: Typestore | None = None) -> ImuOrientation:
    return imu_from_msg(deserialize(raw, IMU, store))


def imu_to_cdr(sample: ImuOrientation, store: Typestore | None = None) -> bytes:
    """A `sensor_msgs/Imu` with the orientation (rates, accelerations and covariances zero)."""
    store = store or typestore()
    types = store.types
    vector = types['geometry_msgs/msg/Vector3']
    x, y, z, w = sample.orientation
    message = types[IMU](
        header=_header(store, sample.stamp_ns, sample.frame_id),
        orientation=types['geometry_msgs/msg/Quaternion'](x=x, y=y, z=z, w=w),
        orientation_covariance=np.zeros(9, dtype=np.float64),
        angular_velocity=vector(x=0.0, y=0.0, z=0.0),
        angular_velocity_covariance=np.zeros(9, dtype=np.float64),
        linear_acceleration=vector(x=0.0, y=0.0, z=0.0),
        linear_acceleration_covariance=np.zeros(9, dtype=np.float64),
    )
    return serialize(message, IMU, store)


def odometry_from_cdr(raw: RawMessage, store: Typestore | None = None) -> OdometrySample:
    return odometry_from_msg(deserialize(raw, ODOMETRY, store))


def odometry_to_cdr(sample: OdometrySample, store: Typestore | None = None) -> bytes:
    """A `nav_msgs/Odometry` with the planar pose (covariances and twist zero)."""
    store = store or typestore()
    types = store.types
    pose = sample.pose
    message = types[ODOMETRY](
        header=_header(store, sample.stamp_ns, sample.frame_id),
        child_frame_id=sample.child_frame_id,
        pose=types['geometry_msgs/msg/PoseWithCovariance'](
            pose=types['geometry_msgs/msg/Pose'](
                position=types['geometry_msgs/msg/Point'](pose.x, pose.y, 0.0),
                orientation=types['geometry_msgs/msg/Quaternion'](
                    0.0, 0.0, math.sin(pose.yaw / 2), math.cos(pose.yaw / 2)
                ),
            ),
            covariance=np.zeros(36, dtype=np.float64),
        ),
        twist=types['geometry_msgs/msg/TwistWithCovariance'](
            twist=types['geometry_msgs/msg/Twist'](
                linear=types['geometry_msgs/msg/Vector3'](0.0, 0.0, 0.0),
                angular=types['geometry_msgs/msg/Vector3'](0.0, 0.0, 0.0),
            ),
            covariance=np.zeros(36, dtype=np.float64),
        ),
    )
    return serialize(message, ODOMETRY, store)


POINT_CLOUD = 'sensor_msgs/msg/PointCloud2'
# sensor_msgs/PointField datatypes of coordinates scanfuse reads.
_FLOAT_FIELDS = {7: 'f4', 8: 'f8'}


@dataclass(frozen=True)
class PointCloud:
    """The x, y, z of a `sensor_msgs/PointCloud2` (N x 3 float32 or float64; NaN points are
    kept: the binning skips them)."""

    points: npt.NDArray[np.floating]
    frame_id: str
    stamp_ns: int


def cloud_from_msg(message: Any) -> PointCloud:
    """x, y, z of every point; organized or not; float32 or float64; no Python loop."""
    fields = {str(f.name): f for f in message.fields}
    missing = [axis for axis in ('x', 'y', 'z') if axis not in fields]
    if missing:
        found = ', '.join(sorted(fields)) or 'none'
        msg = (
            f'PointCloud2 in frame {message.header.frame_id!r} has no {", ".join(missing)} '
            f'field (fields: {found}); scanfuse needs x, y and z'
        )
        raise MessageError(msg)
    width, height = int(message.width), int(message.height)
    point_step, row_step = int(message.point_step), int(message.row_step)
    order = '>' if message.is_bigendian else '<'
    formats, offsets = [], []
    for axis in ('x', 'y', 'z'):
        field = fields[axis]
        kind = _FLOAT_FIELDS.get(int(field.datatype))
        if kind is None or int(field.count) != 1:
            msg = (
                f'PointCloud2 field {axis} has datatype {int(field.datatype)} and count '
                f'{int(field.count)}; scanfuse reads FLOAT32 (7) or FLOAT64 (8) coordinates'
            )
            raise MessageError(msg)
        formats.append(order + kind)
        offsets.append(int(field.offset))
        if int(field.offset) + np.dtype(kind).itemsize > point_step:
            msg = (
                f'PointCloud2 field {axis} at offset {int(field.offset)} does not fit in a '
                f'point_step of {point_step} bytes; the message is inconsistent'
            )
            raise MessageError(msg)
    data = np.frombuffer(message.data, dtype=np.uint8)
    if width * point_step > row_step or row_step * height > data.size:
        msg = (
            f'PointCloud2 of {width}x{height} points with point_step {point_step} and row_step '
            f'{row_step} needs {row_step * height} bytes, got {data.size}'
        )
        raise MessageError(msg)
    rows = data[: row_step * height].reshape(height, row_step)[:, : width * point_step]
    # The message's bytes when rows are not padded (the usual case): no copy.
    flat = np.ascontiguousarray(rows).reshape(-1)
    count = width * height
    points: npt.NDArray[np.floating]
    spacing = offsets[1] - offsets[0]
    if count == 0:
        points = np.empty((0, 3), np.result_type(*formats))
    elif len(set(formats)) == 1 and spacing > 0 and offsets[2] - offsets[1] == spacing:
        # x, y, z evenly spaced in each point (x, y, z, padding...: PCL's layouts): one
        # strided N x 3 view, which the binning kernel reads as it is.
        points = np.ndarray((count, 3), formats[0], flat, offsets[0], (point_step, spacing))
    else:
        columns = [
            np.ndarray((count,), kind, flat, offset, (point_step,))
            for kind, offset in zip(formats, offsets, strict=True)
        ]
        points = np.stack(columns, axis=1)
    return PointCloud(
        points, frame_name(str(message.header.frame_id)), stamp_to_ns(message.header.stamp)
    )


def cloud_from_cdr(raw: RawMessage, store: Typestore | None = None) -> PointCloud:
    return cloud_from_msg(deserialize(raw, POINT_CLOUD, store))


def cloud_to_cdr(
    points: npt.NDArray[np.floating],
    *,
    frame_id: str,
    stamp_ns: int,
    dtype: str = 'f4',
    extra_bytes: int = 4,
    store: Typestore | None = None,
) -> bytes:
    """A PointCloud2 of `points` (x, y, z; `dtype` f4 or f8; padding after): unorganized
    for N x 3 points, organized (height x width) for height x width x 3."""
    store = store or typestore()
    types = store.types
    array = np.asarray(points)
    height, width = array.shape[:2] if array.ndim == 3 else (1, len(array))
    size = np.dtype(dtype).itemsize
    step = 3 * size + extra_bytes
    count = height * width
    buffer = np.zeros((count, step), dtype=np.uint8)
    coordinates = np.ascontiguousarray(array.reshape(count, 3), dtype='<' + dtype)
    buffer[:, : 3 * size] = coordinates.view(np.uint8).reshape(count, 3 * size)
    datatype = 7 if dtype == 'f4' else 8
    fields = [
        types['sensor_msgs/msg/PointField'](name=axis, offset=i * size, datatype=datatype, count=1)
        for i, axis in enumerate('xyz')
    ]
    message = types[POINT_CLOUD](
        header=_header(store, stamp_ns, frame_id),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * width,
        data=buffer.reshape(-1),
        is_dense=False,
    )
    return serialize(message, POINT_CLOUD, store)
