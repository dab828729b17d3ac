"""`scanfuse calibrate`: the depth camera's mounting estimated from a recorded bag.

Reads a bag as `scanfuse bag` does (rosbags' `AnyReader`, the same topic choice, TF and
CameraInfo), pairs depth frames with the LiDAR scan nearest in stamp (leaving out, when
the bag has odometry, the pairs between which the robot moved), and hands them to
`scanfuse.calibrate.calibrate`. The LiDAR's mounting (TF, else the `lidar_*` parameters) is
trusted; the camera's (TF, else the `camera_*` parameters) is only the starting point.
`save_calibration` writes the parameter snippet, the numbers as JSON and the figure.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.table import Table

from scanfuse.calibrate import (
    CalibrationFrame,
    CalibrationSettings,
    Mounting,
    body_to_optical_command,
    calibrate,
    pair_motion,
    static_transform_command,
)
from scanfuse.config import FusionConfig
from scanfuse.errors import BagError, CalibrationError
from scanfuse.frames import frame_name
from scanfuse.ros.bag import _BagJob, _located, _open_reader, describe_topics
from scanfuse.ros.messages import (
    IMAGE,
    LASER_SCAN,
    ODOMETRY,
    DepthImage,
    Distro,
    camera_from_msg,
    check_depth_matches_camera,
    depth_from_msg,
    deserialize,
    odometry_from_msg,
    scan_from_msg,
)
from scanfuse.transforms import BODY_TO_OPTICAL, Extrinsics, Transform

if TYPE_CHECKING:
    from rosbags.highlevel import AnyReader

    from scanfuse.calibrate import Calibration
    from scanfuse.camera import CameraModel
    from scanfuse.scan import Scan

# Depth frames handed to the estimate at most (spread evenly over the bag).
MAX_FRAMES = 60


@dataclass(frozen=True)
class BagCalibration:
    """The calibration of one bag and where its inputs came from."""

    calibration: Calibration
    bag: Path
    scan_topic: str
    depth_topic: str
    base_frame: str
    optical_frame: str
    body_frame: str  # the camera body frame the static transform names
    body_in_tf: bool  # the bag's TF already holds body_frame (replace its transform)
    parent_frame: str  # body_frame's parent in the bag's TF, else base_frame
    base_to_parent: Transform  # its pose in the base frame (identity: the base itself)
    given_source: str
    lidar_source: str
    odometry_topic: str = ''  # odometry that showed which frames the robot stood still in
    moving_frames: int = 0  # depth frames left out: the robot moved between them and scans

    def parameters_yaml(self) -> str:
        return self.calibration.mounting.parameters_yaml()

    def commands(self) -> list[str]:
        """The static transform(s) that publish the estimate: parent -> body (the body
        frame's parent in the bag's TF, else the base frame), and body -> optical when the
        bag's TF has no body frame above the optical one."""
        pose = self.base_to_parent.inverse() @ self.calibration.mounting.body
        lines = [static_transform_command(pose, self.parent_frame, self.body_frame)]
        if not self.body_in_tf:
            lines.append(body_to_optical_command(self.body_frame, self.optical_frame))
        return lines

    def tables(self) -> tuple[Table, Table]:
        """Given, estimated and their difference per parameter; then the residuals."""
        result = self.calibration
        table = Table(title=f'scanfuse calibrate: {self.bag}')
        table.add_column('parameter')
        for name in ('given', 'estimated', 'change'):
            table.add_column(name, justify='right')
        given, found, change = result.given, result.mounting, result.corrections
        for name in ('x', 'y', 'height'):
            values = (getattr(given, name), getattr(found, name), getattr(change, name))
            table.add_row(f'camera_{name} (m)', *(f'{v:+.3f}' for v in values))
        for name in ('roll', 'pitch', 'yaw'):
            values = (getattr(given, name), getattr(found, name), getattr(change, name))
            table.add_row(f'camera_{name} (deg)', *(f'{math.degrees(v):+.2f}' for v in values))
        spread = result.frame_spread
        residuals = Table(show_header=False)
        residuals.add_column('what')
        residuals.add_column('value', justify='right')
        rows = (
            ('given mounting from', self.given_source),
            ('LiDAR mounting from', self.lidar_source),
            ('topics', f'{self.scan_topic} + {self.depth_topic}'),
            ('frames used (floor / scan match)', f'{result.floor_frames} / {result.match_frames}'),
            (
                'frames left out (robot moving)',
                f'{self.moving_frames} (by {self.odometry_topic})'
                if self.odometry_topic
                else 'no odometry: record standing still',
            ),
            ('floor RMS', f'{result.floor_rms * 1e3:.1f} mm'),
            (
                'scan match RMS (given -> estimated)',
                (
                    f'{result.match_rms_given * 1e3:.1f} -> {result.match_rms * 1e3:.1f} mm '
                    f'({result.match_sigmas_given:.2f} -> {result.match_sigmas:.2f} sigma)'
                ),
            ),
            (
                'frame-to-frame spread of x, y, yaw',
                (
                    f'{spread[0] * 1e3:.1f} mm, {spread[1] * 1e3:.1f} mm, '
                    f'{math.degrees(spread[2]):.2f} deg'
                ),
            ),
            (
                'camera points on the LiDAR lines (given -> estimated)',
                f'{result.matched_given} -> {result.matched_points} of {result.camera_count}',
            ),
        )
        for name, value in rows:
            residuals.add_row(name, value)
        return table, residuals

    def summary(self) -> dict[str, object]:
        """The numbers, JSON-ready (metres and radians)."""
        result = self.calibration
        return {
            'bag': str(self.bag),
            'estimated': result.mounting.parameters(),
            'given': result.given.parameters(),
            'given_source': self.given_source,
            'lidar_source': self.lidar_source,
            'frames': result.frames,
            'floor_frames': result.floor_frames,
            'floor_rms': result.floor_rms,
            'match_frames': result.match_frames,
            'moving_frames': self.moving_frames,
            'odometry_topic': self.odometry_topic,
            'matched_points': result.matched_points,
            'matched_given': result.matched_given,
            'camera_points': result.camera_count,
            'match_rms': result.match_rms,
            'match_rms_given': result.match_rms_given,
            'match_sigmas': result.match_sigmas,
            'match_sigmas_given': result.match_sigmas_given,
            'frame_spread': {
                'x': result.frame_spread[0],
                'y': result.frame_spread[1],
                'yaw': result.frame_spread[2],
            },
            'commands': self.commands(),
        }


def calibrate_bag(
    input: str | Path,  # noqa: A002 - the name the CLI shows
    *,
    config: FusionConfig | None = None,
    scan_topic: str | None = None,
    depth_topic: str | None = None,
    camera_info_topic: str | None = None,
    max_frames: int = MAX_FRAMES,
    settings: CalibrationSettings | None = None,
    distro: Distro = Distro.HUMBLE,
) -> BagCalibration:
    """The camera's mounting from the depth frames and LiDAR scans of a bag (`settings`:
    the defaults with `config`'s depth_noise)."""
    config = config or FusionConfig()
    source = Path(input)
    if not source.exists():
        msg = f'bag {source} does not exist; give the folder or file `ros2 bag record` wrote'
        raise BagError(msg)
    settings = settings or CalibrationSettings(depth_noise=config.depth_noise)
    with _open_reader(source, distro) as reader:
        job = _CalibrationJob(reader, config, distro)
        with _located(job):
            job.choose(scan_topic, depth_topic, camera_info_topic)
            frames = job.read(max_frames, settings)
    result = calibrate(frames, job.camera, job.base_to_laser, job.given, settings)
    return BagCalibration(
        calibration=result,
        bag=source,
        scan_topic=job.scan_topic,
        depth_topic=job.depth_topic,
        base_frame=frame_name(config.base_frame),
        optical_frame=job.optical_frame,
        body_frame=job.body_frame,
        body_in_tf=job.body_in_tf,
        parent_frame=job.parent_frame,
        base_to_parent=job.base_to_parent,
        given_source=job.given_source,
        lidar_source=job.lidar_source,
        odometry_topic=job.odometry_topic,
        moving_frames=job.moving_frames,
    )


def save_calibration(found: BagCalibration, out: Path) -> list[Path]:
    """calibration.yaml (the parameters), calibration.json (every number), calibration.png."""
    from scanfuse.evaluate.calibration_figure import calibration_figure  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    written = [out / 'calibration.yaml', out / 'calibration.json', out / 'calibration.png']
    header = ''.join(f'# {line}\n' for line in found.commands())
    written[0].write_text(header + found.parameters_yaml(), encoding='utf-8')
    text = json.dumps(found.summary(), indent=2, allow_nan=True)
    written[1].write_text(text + '\n', encoding='utf-8')
    calibration_figure(found.calibration, f'scanfuse calibrate: {found.bag.name}', written[2])
    return written


class _CalibrationJob(_BagJob):
    """The reading half of `fuse_bag`'s job: topics, TF, CameraInfo, then scans and frames."""

    def __init__(self, reader: AnyReader, config: FusionConfig, distro: Distro) -> None:
        super().__init__(reader, config, distro, write_depth_scan=False)
        self.scan_topic = self.depth_topic = self.info_topic = ''
        self.optical_frame = self.body_frame = ''
        self.body_in_tf = False
        self.parent_frame = frame_name(config.base_frame)
        self.base_to_parent = Transform()
        self.given_source = self.lidar_source = ''
        self.base_to_laser = Transform()
        self.given = Mounting(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self.odometry_topic = ''
        self.moving_frames = 0
        self._camera: CameraModel | None = None

    @property
    def camera(self) -> CameraModel:
        assert self._camera is not None
        return self._camera

    def _output_topics(self) -> set[str]:
        return set()  # nothing is written: a fused bag calibrates as well as its input

    def choose(self, scan: str | None, depth: str | None, camera_info: str | None) -> None:
        kinds = set(self.topics_types.values())
        for msgtype, what in ((LASER_SCAN, 'LiDAR scans (LaserScan)'), (IMAGE, 'depth images')):
            if msgtype not in kinds:
                msg = (
                    f'no {what} in bag {self.source} (topics: '
                    f'{describe_topics(self.topics_types)}); calibrate needs the LiDAR and the '
                    'depth camera recorded together: ros2 bag record /scan '
                    '/camera/depth/image_raw /camera/depth/camera_info /tf_static'
                )
                raise BagError(msg)
        choice = self.choose_topics(scan, depth, camera_info)
        self.scan_topic, self.depth_topic = choice.scan, choice.depth
        self.info_topic = choice.camera_info

    def read(self, max_frames: int, settings: CalibrationSettings) -> list[CalibrationFrame]:
        """The mounting and camera first, then depth frames paired with scans."""
        info = self.first_message(self.info_topic)
        scan = self.first_message(self.scan_topic)
        depth = self.first_message(self.depth_topic)
        if info is None or scan is None or depth is None:
            empty = next(
                t
                for t, m in (
                    (self.info_topic, info),
                    (self.scan_topic, scan),
                    (self.depth_topic, depth),
                )
                if m is None
            )
            msg = f'topic {empty} has no messages; calibrate needs it'
            raise BagError(msg)
        self._camera = camera_from_msg(info)
        laser = frame_name(str(scan.header.frame_id))
        self.optical_frame = frame_name(str(depth.header.frame_id) or str(info.header.frame_id))
        self._read_mounting()
        self._mountings(laser)
        return self._frames(max_frames, settings)

    def _mountings(self, laser: str) -> None:
        config, tf = self.config, self.stream.tf
        base = frame_name(config.base_frame)
        self.base_to_laser = self.stream.base_to_laser(laser)
        tf_laser = config.use_tf and tf.can_transform(base, laser)
        self.lidar_source = f'TF ({base} -> {laser})' if tf_laser else 'the lidar_* parameters'
        optical = self.optical_frame
        if config.use_tf and tf.can_transform(base, optical):
            given = Transform.from_matrix(tf.lookup(base, optical))
            self.given_source = f'TF ({base} -> {optical})'
        else:
            given = Extrinsics.from_config(config).base_to_camera_optical
            self.given_source = 'the camera_* parameters'
        self.given = Mounting.of_optical(given)
        self.body_frame, self.body_in_tf = self._body_frame(base, optical)
        if self.body_in_tf:
            self.parent_frame = self._parent(base, self.body_frame)
            self.base_to_parent = Transform.from_matrix(tf.lookup(base, self.parent_frame))

    def _body_frame(self, base: str, optical: str) -> tuple[str, bool]:
        """The frame above the optical one turned from it as every camera body is (the one
        nearest the base), else a name made from the optical frame's."""
        tf = self.stream.tf
        if tf.can_transform(base, optical):
            wanted = BODY_TO_OPTICAL.matrix
            bodies = [
                frame
                for frame in tf.chain(base, optical) - {optical}
                if np.allclose(tf.lookup(frame, optical), wanted, atol=1e-6)
            ]
            if bodies:
                return min(bodies, key=lambda frame: len(tf.chain(base, frame))), True
        for suffix, replacement in (('_optical_frame', '_frame'), ('_optical', '')):
            if optical.endswith(suffix) and optical != suffix:
                return optical.removesuffix(suffix) + replacement, False
        return f'{optical}_body', False

    def _parent(self, base: str, frame: str) -> str:
        """`frame`'s parent in the TF tree below `base` (`base` itself for a child of it)."""
        tf = self.stream.tf
        chain = tf.chain(base, frame)  # the child frames from base down to `frame`
        above = [f for f in chain - {frame} if len(tf.chain(base, f)) == len(chain) - 1]
        return above[0] if above else base

    def _odometry(self) -> tuple[list[int], list[tuple[float, float, float]]]:
        """Stamps and planar poses of the odometry topic, if the bag has it."""
        topic = self.config.odom_topic
        if self.topics_types.get(topic) != ODOMETRY:
            return [], []
        self.odometry_topic = topic
        samples = sorted(
            (
                odometry_from_msg(self.decode(connection, raw))
                for connection, _, raw in self.messages(self.connections(topic))
            ),
            key=lambda sample: sample.stamp_ns,
        )
        poses = [(s.pose.x, s.pose.y, s.pose.yaw) for s in samples]
        return [s.stamp_ns for s in samples], poses

    def _still(
        self, pairs: list[tuple[DepthImage, Scan]], settings: CalibrationSettings
    ) -> list[tuple[DepthImage, Scan]]:
        """The pairs between whose stamps odometry says the robot stood still (all of them
        without odometry, or where it does not cover the stamps)."""
        stamps, poses = self._odometry()
        if not stamps or not pairs:
            return pairs
        shift, turn = pair_motion(
            [image.stamp_ns for image, _ in pairs],
            [scan.stamp_ns for _, scan in pairs],
            stamps,
            poses,
        )
        with np.errstate(invalid='ignore'):
            moving = (shift > settings.still_shift) | (turn > settings.still_turn)
        self.moving_frames = int(moving.sum())
        if moving.all():
            msg = (
                f'the robot moved between every depth frame and its scan (by {self.odometry_topic}'
                f': up to {np.nanmax(shift) * 100:.1f} cm, {math.degrees(np.nanmax(turn)):.1f} '
                'deg); calibrate needs the robot standing still for a few seconds'
            )
            raise CalibrationError(msg)
        return [pair for pair, away in zip(pairs, moving, strict=True) if not away]

    def _frames(self, max_frames: int, settings: CalibrationSettings) -> list[CalibrationFrame]:
        depth_connections = self.connections(self.depth_topic)
        count = sum(c.msgcount for c in depth_connections)
        stride = max(1, math.ceil(count / max(1, max_frames)))
        scans: list[Scan] = []
        images: list[DepthImage] = []
        index = 0
        connections = [*self.connections(self.scan_topic), *depth_connections]
        for connection, _, raw in self.messages(connections):
            if connection.topic == self.scan_topic:
                cdr = self.to_cdr(connection, raw)
                scans.append(scan_from_msg(self.decode_cdr(cdr, LASER_SCAN)))
                continue
            if index % stride == 0:
                cdr = self.to_cdr(connection, raw)
                image = depth_from_msg(self.decode_cdr(cdr, IMAGE))
                check_depth_matches_camera(image, self.camera)
                images.append(image)
            index += 1
        if not scans or not images:
            msg = f'no LiDAR scans or depth frames could be read from {self.source}'
            raise BagError(msg)
        stamps = np.array([s.stamp_ns for s in scans], dtype=np.int64)
        order = np.argsort(stamps)
        stamps = stamps[order]
        window = round(self.config.max_time_offset * 1e9)
        pairs: list[tuple[DepthImage, Scan]] = []
        for image in images:
            at = int(np.searchsorted(stamps, image.stamp_ns))
            near = [i for i in (at - 1, at) if 0 <= i < stamps.size]
            best = min(near, key=lambda i: abs(int(stamps[i]) - image.stamp_ns))
            if abs(int(stamps[best]) - image.stamp_ns) <= window:
                pairs.append((image, scans[int(order[best])]))
        if not pairs:
            msg = (
                f'no depth frame of {self.depth_topic} has a scan of {self.scan_topic} within '
                f'max_time_offset = {self.config.max_time_offset} s; are the two stamped by '
                'the same clock? (raise max_time_offset in --params if they are)'
            )
            raise BagError(msg)
        return [CalibrationFrame(image.depth, scan) for image, scan in self._still(pairs, settings)]

    def decode_cdr(self, cdr: bytes, msgtype: str) -> Any:
        return deserialize(cdr, msgtype, self.store)
