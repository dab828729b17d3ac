"""The sources beyond the first LiDAR and camera: their latest messages and what they add.

`FusionStream` fuses the first LiDAR with the first camera; every output scan then takes,
from each other named source (`scanfuse.sources`), its freshest message within that
source's own `max_time_offset` of the output stamp, moved to the output stamp through
odometry and into the output frame point by point (not resampled by angle as if the
sensors shared an origin):

- another LiDAR: its readings as points (de-skewed when it rotates), nearest per slot;
- another depth camera: the obstacle method with that camera's mounting and slab;
- a point cloud: its points inside the slab, with the obstacle method's per-slot estimate.

A source with nothing fresh is passed over and counted per source (`missing`); one whose
frame TF knows but cannot relate to the base is passed over too (`no_mounting`). The other
cameras' frames an output used are kept (`seen`): the stream's obstacle memory forgets what
they see free, as it does with the first camera's.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from scanfuse.convert.cloud import lidar_points, points_scan
from scanfuse.errors import ScanfuseError
from scanfuse.frames import frame_name
from scanfuse.pipeline import FusionPipeline
from scanfuse.scan import normalized_ranges
from scanfuse.transforms import BODY_TO_OPTICAL, Extrinsics, Transform

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.config import FusionConfig
    from scanfuse.motion import PlanarMotion
    from scanfuse.scan import Scan
    from scanfuse.sources import CameraSource, CloudSource, LidarSource, Mounting

# Messages kept per source: the freshest within max_time_offset is all that is used.
KEEP = 8


class Locator(Protocol):
    """What the stream knows of frames and motion, for the sources."""

    def mounting(self, frame: str, fallback: Transform) -> Transform | None: ...

    def motion_to(
        self, source_ns: int, target_ns: int, base_to_sensor: Transform
    ) -> PlanarMotion | None: ...

    def deskewed(self, scan: Scan) -> Scan: ...


def mounting_transform(mounting: Mounting) -> Transform:
    """A source's body pose in the base frame from its x, y, z, roll, pitch, yaw."""
    return Transform.from_rpy(
        mounting.roll, mounting.pitch, mounting.yaw, (mounting.x, mounting.y, mounting.z)
    )


@dataclass
class _Message:
    stamp_ns: int
    frame_id: str
    data: object
    camera: CameraModel | None = None


@dataclass
class _Source:
    name: str
    max_offset_ns: int
    messages: deque[_Message] = field(default_factory=lambda: deque(maxlen=KEEP))

    def freshest(self, stamp_ns: int) -> _Message | None:
        """The newest message within max_time_offset of `stamp_ns`."""
        near = [m for m in self.messages if abs(m.stamp_ns - stamp_ns) <= self.max_offset_ns]
        return max(near, key=lambda m: m.stamp_ns) if near else None


@dataclass(frozen=True)
class SeenFrame:
    """A depth frame of another camera that an output scan used, for the memory to clear."""

    name: str
    stamp_ns: int
    depth: npt.NDArray[np.generic]
    camera: CameraModel
    base_to_optical: Transform
    slab: tuple[float, float]


@dataclass
class ExtraCounts:
    used: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)
    no_mounting: dict[str, int] = field(default_factory=dict)
    no_return: dict[str, int] = field(default_factory=dict)  # cloud points at (0, 0, 0)

    def note(self, table: dict[str, int], name: str) -> None:
        table[name] = table.get(name, 0) + 1


class ExtraSources:
    """Every named source but the first LiDAR and the first camera."""

    def __init__(self, config: FusionConfig) -> None:
        self.config = config
        sources = config.sources
        self.lidars = {s.name: s for s in sources.lidars[1:]}
        self.cameras = {s.name: s for s in sources.cameras[1:]}
        self.clouds = {s.name: s for s in sources.clouds}
        every: list[LidarSource | CameraSource | CloudSource] = [
            *self.lidars.values(),
            *self.cameras.values(),
            *self.clouds.values(),
        ]
        self._state = {
            s.name: _Source(
                s.name,
                round(
                    (config.max_time_offset if s.max_time_offset is None else s.max_time_offset)
                    * 1e9
                ),
            )
            for s in every
        }
        self._camera_models: dict[str, CameraModel] = {}
        self._pipelines = {
            name: FusionPipeline(camera_config(config, s)) for name, s in self.cameras.items()
        }
        self.counts = ExtraCounts()
        self.seen: list[SeenFrame] = []  # the other cameras' frames the last output used

    @property
    def names(self) -> list[str]:
        return list(self._state)

    def __contains__(self, name: object) -> bool:
        return name in self._state

    # ------------------------------------------------------------ inputs

    def add_scan(self, name: str, scan: Scan) -> None:
        # A driver's error values (a Hokuyo's 0.0 "no return") are no readings: NaN, as the
        # first LiDAR's are (`normalized_ranges`), not points at the sensor's own origin.
        scan = scan.with_ranges(normalized_ranges(scan))
        self._state[name].messages.append(_Message(scan.stamp_ns, scan.frame_id, scan))

    def add_camera_info(self, name: str, camera: CameraModel) -> None:
        if self._camera_models.get(name) != camera:
            self._camera_models[name] = camera
            self._state[name].messages.clear()

    def add_depth(
        self, name: str, stamp_ns: int, depth: npt.NDArray[np.generic], frame_id: str
    ) -> None:
        camera = self._camera_models.get(name)
        if camera is None:
            return
        camera.check_depth(depth)
        self._state[name].messages.append(_Message(stamp_ns, frame_id, depth, camera))

    def add_cloud(
        self, name: str, stamp_ns: int, points: npt.NDArray[np.floating], frame_id: str
    ) -> None:
        # Ouster, Hesai and Livox drivers write (0, 0, 0) for a beam without a return: no
        # point at all, not an obstacle at the sensor's own origin. Dropped, counted.
        no_return = np.all(points == 0.0, axis=1)
        dropped = int(np.count_nonzero(no_return))
        if dropped:
            points = points[~no_return]
            self.counts.no_return[name] = self.counts.no_return.get(name, 0) + dropped
        self._state[name].messages.append(_Message(stamp_ns, frame_name(frame_id), points))

    # ------------------------------------------------------------ contributions

    def contributions(
        self, output: Scan, base_to_output: Transform, locator: Locator
    ) -> tuple[list[Scan], list[Scan]]:
        """(LiDAR scans, obstacle scans) of the other sources on the output grid and stamp."""
        lidars: list[Scan] = []
        obstacles: list[Scan] = []
        self.seen = []
        for name, state in self._state.items():
            message = state.freshest(output.stamp_ns)
            if message is None:
                self.counts.note(self.counts.missing, name)
                continue
            try:
                scan = self._contribution(name, message, output, base_to_output, locator)
            except ScanfuseError:
                scan = None
            if scan is None:
                self.counts.note(self.counts.no_mounting, name)
                continue
            self.counts.note(self.counts.used, name)
            (lidars if name in self.lidars else obstacles).append(scan)
        return lidars, obstacles

    def _contribution(
        self,
        name: str,
        message: _Message,
        output: Scan,
        base_to_output: Transform,
        locator: Locator,
    ) -> Scan | None:
        config = self.config
        if name in self.lidars:
            source: LidarSource | CameraSource | CloudSource = self.lidars[name]
            mount = locator.mounting(message.frame_id, mounting_transform(source))
            motion = locator.motion_to(message.stamp_ns, output.stamp_ns, base_to_output)
            if mount is None or motion is None:
                return None
            scan = locator.deskewed(message.data)  # type: ignore[arg-type]
            points = lidar_points(scan)
            return self._points(
                points, mount, base_to_output, output, motion, -np.inf, np.inf, 1, np.inf
            )
        if name in self.cameras:
            camera_source = self.cameras[name]
            assert message.camera is not None
            optical = message.frame_id or message.camera.frame_id
            fallback = mounting_transform(camera_source) @ BODY_TO_OPTICAL
            mount = locator.mounting(optical, fallback)
            motion = locator.motion_to(message.stamp_ns, output.stamp_ns, base_to_output)
            if mount is None or motion is None:
                return None
            extrinsics = Extrinsics(base_to_laser=base_to_output, base_to_camera_optical=mount)
            depth: npt.NDArray[np.generic] = message.data  # type: ignore[assignment]
            result = self._pipelines[name].fuse(output, depth, message.camera, extrinsics, motion)
            own = self._pipelines[name].config
            self.seen.append(
                SeenFrame(
                    name,
                    message.stamp_ns,
                    depth,
                    message.camera,
                    mount,
                    (own.min_obstacle_height, own.max_obstacle_height),
                )
            )
            return result.depth_scan
        cloud = self.clouds[name]
        mount = locator.mounting(message.frame_id, mounting_transform(cloud))
        motion = locator.motion_to(message.stamp_ns, output.stamp_ns, base_to_output)
        if mount is None or motion is None:
            return None
        points = np.asarray(message.data).reshape(-1, 3)
        low = config.min_obstacle_height if cloud.min_height is None else cloud.min_height
        high = config.max_obstacle_height if cloud.max_height is None else cloud.max_height
        return self._points(
            points,
            mount,
            base_to_output,
            output,
            motion,
            low,
            high,
            config.obstacle_min_points,
            config.obstacle_cluster_spread,
            range_max=cloud.range_max,
        )

    @staticmethod
    def _points(
        points: npt.NDArray[np.floating],
        base_to_sensor: Transform,
        base_to_output: Transform,
        output: Scan,
        motion: PlanarMotion,
        low: float,
        high: float,
        min_points: int,
        spread: float,
        *,
        range_max: float | None = None,
    ) -> Scan:
        scan = points_scan(
            points,
            base_to_sensor,
            base_to_output,
            output.grid,
            motion=motion,
            min_height=low,
            max_height=high,
            range_min=output.range_min,
            range_max=output.range_max if range_max is None else range_max,
            min_points=min_points,
            cluster_spread=spread,
        )
        return scan.with_ranges(scan.ranges, frame_id=output.frame_id, stamp_ns=output.stamp_ns)


def camera_config(config: FusionConfig, source: CameraSource) -> FusionConfig:
    """The fusion settings of one camera: its own slab and pairing window where it sets them."""
    changes = {}
    if source.max_time_offset is not None:
        changes['max_time_offset'] = source.max_time_offset
    if source.min_obstacle_height is not None:
        changes['min_obstacle_height'] = source.min_obstacle_height
    if source.max_obstacle_height is not None:
        changes['max_obstacle_height'] = source.max_obstacle_height
    return config.with_changes(**changes) if changes else config


def primary_camera_config(config: FusionConfig) -> FusionConfig:
    """The fusion settings of the camera paired with the first LiDAR: the first named one's
    own (`camera_config`), or `config` itself when no camera is named."""
    cameras = config.sources.cameras
    return camera_config(config, cameras[0]) if cameras else config
