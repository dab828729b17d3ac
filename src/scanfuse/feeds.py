"""Every source but the one that triggers an output: its latest messages, and one rule for
what it adds.

Each output scan takes, from every other source, one message within that source's own
`max_time_offset` of the output stamp, moved to the output stamp through odometry and into
the output frame point by point (not resampled by angle as if the sensors shared an origin).
The output waits for the depth cameras (`FusionStream` holds it until each has a frame at or
after its stamp, or is silent, or the wait is over), so a camera's frame is the one nearest
the stamp; LiDARs and clouds are not waited for, so theirs is the freshest:

- a LiDAR: its readings as points (de-skewed when it rotates), nearest per slot;
- a depth camera (`CameraFeed`): the obstacle (or row) method with that camera's mounting,
  slab and ground; every camera, the one-source parameters' included, takes this one path;
- a point cloud: its points inside the slab, with the obstacle method's per-slot estimate.

A source with nothing near enough is passed over and counted per source (`missing`); one
whose frame TF knows but cannot relate to the base is passed over too (`no_mounting`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from scanfuse.convert.cloud import lidar_points, points_scan
from scanfuse.convert.ground import GroundSettings, GroundTracker
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

# Messages kept per LiDAR or cloud: the freshest within max_time_offset is all that is used.
KEEP = 8
# Frames kept per camera: at 30 Hz and max_time_offset 0.1 s about 7 are ever useful.
MAX_FRAMES = 16
# The name of the camera the one-source parameters (`depth_topic`...) describe when no camera
# is named.
SHORTHAND_CAMERA = 'camera'


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


@dataclass(frozen=True)
class DepthFrame:
    """A depth image (uint16 mm or float32 m) with its stamp, frame and camera."""

    stamp_ns: int
    depth: npt.NDArray[np.generic]
    camera: CameraModel
    frame_id: str = ''

    @property
    def optical_frame(self) -> str:
        return frame_name(self.frame_id or self.camera.frame_id)


class CameraFeed:
    """One depth camera: its calibration, recent frames, fusion settings, floor, and what
    the memory last cleared with. Every camera is one of these."""

    def __init__(
        self,
        name: str,
        config: FusionConfig,
        depth_topic: str,
        camera_info_topic: str,
        base_to_optical: Transform,
    ) -> None:
        self.name = name
        self.config = config  # the global settings with this camera's own section applied
        self.depth_topic = depth_topic
        self.camera_info_topic = camera_info_topic
        self.base_to_optical = base_to_optical  # the mounting parameters (TF may override)
        self.pipeline = FusionPipeline(config)
        self.max_offset_ns = round(config.max_time_offset * 1e9)
        self.model: CameraModel | None = None
        self.frames: deque[DepthFrame] = deque(maxlen=MAX_FRAMES)
        self.last_arrival_ns: int | None = None
        self.ground: GroundTracker | None = None
        self.ground_frame_ns: int | None = None  # the frame `ground` was last updated with
        self.cleared_with: int | None = None  # the frame the memory last forgot with
        # `far_confirm`: the far slab readings' places (odometry frame) of the frame last
        # fused (`far_frame`, its odometry segment `far_segment`) and of the one before it,
        # which confirms them.
        self.far_frame: int | None = None
        self.far_segment: int | None = None
        self.far_now: npt.NDArray[np.float64] = np.zeros((0, 2))
        self.far_before: npt.NDArray[np.float64] = np.zeros((0, 2))

    @property
    def slab(self) -> tuple[float, float]:
        return (self.config.min_obstacle_height, self.config.max_obstacle_height)

    def keep_state_of(self, old: CameraFeed) -> None:
        """What `old` (this camera before a reconfiguration) has received stays; its floor
        too while its settings hold."""
        self.model, self.frames = old.model, old.frames
        self.last_arrival_ns, self.cleared_with = old.last_arrival_ns, old.cleared_with
        self.far_frame, self.far_now, self.far_before = old.far_frame, old.far_now, old.far_before
        self.far_segment = old.far_segment
        if (
            old.ground is not None
            and self.ground is not None
            and old.ground.settings == self.ground.settings
        ):
            self.ground = old.ground

    def track_ground(self, on: bool) -> None:
        self.ground = GroundTracker(GroundSettings.from_config(self.config)) if on else None

    def add_camera_info(self, camera: CameraModel) -> None:
        """A (new) calibration: frames of the old one are dropped."""
        if camera != self.model:
            self.model = camera
            self.frames.clear()

    def add_depth(
        self, stamp_ns: int, depth: npt.NDArray[np.generic], frame_id: str, now_ns: int
    ) -> DepthFrame:
        """The frame, kept (ScanfuseError when it does not fit the calibration)."""
        assert self.model is not None
        self.model.check_depth(depth)
        self.last_arrival_ns = now_ns
        frame = DepthFrame(stamp_ns, depth, self.model, frame_id)
        self.frames.append(frame)
        return frame

    def nearest(self, stamp_ns: int) -> DepthFrame | None:
        """The frame nearest `stamp_ns` within this camera's max_time_offset."""
        best: DepthFrame | None = None
        best_offset = self.max_offset_ns + 1
        for frame in self.frames:
            offset = abs(frame.stamp_ns - stamp_ns)
            if offset < best_offset:  # of two equally near, the earlier one (frames ascend)
                best, best_offset = frame, offset
        return best

    def has_frame_from(self, stamp_ns: int) -> bool:
        """A frame stamped at or after `stamp_ns` has come: frames come in stamp order, so
        no later one can be nearer."""
        return bool(self.frames) and self.frames[-1].stamp_ns >= stamp_ns

    def prune(self, oldest_ns: int) -> None:
        """Frames no output stamped from `oldest_ns` on can take."""
        while len(self.frames) > 1 and self.frames[0].stamp_ns + self.max_offset_ns < oldest_ns:
            self.frames.popleft()


def camera_feeds(config: FusionConfig) -> dict[str, CameraFeed]:
    """Every camera: the named ones, else the one the one-source parameters describe."""
    named = config.sources.cameras
    if named:
        return {
            source.name: CameraFeed(
                source.name,
                camera_config(config, source),
                source.depth_topic,
                source.camera_info_topic,
                mounting_transform(source) @ BODY_TO_OPTICAL,
            )
            for source in named
        }
    if not config.has_camera:
        return {}
    mount = Extrinsics.from_config(config).base_to_camera_optical
    feed = CameraFeed(SHORTHAND_CAMERA, config, config.depth_topic, config.camera_info_topic, mount)
    return {feed.name: feed}


@dataclass
class _Message:
    stamp_ns: int
    frame_id: str
    data: object


@dataclass
class _Source:
    name: str
    max_offset_ns: int
    messages: deque[_Message] = field(default_factory=lambda: deque(maxlen=KEEP))

    def freshest(self, stamp_ns: int) -> _Message | None:
        """The newest message within max_time_offset of `stamp_ns`."""
        near = [m for m in self.messages if abs(m.stamp_ns - stamp_ns) <= self.max_offset_ns]
        return max(near, key=lambda m: m.stamp_ns) if near else None


@dataclass
class SourceCounts:
    """Per source: outputs it was used in, had nothing for, could not be placed for."""

    used: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)
    no_mounting: dict[str, int] = field(default_factory=dict)
    no_return: dict[str, int] = field(default_factory=dict)  # cloud points at (0, 0, 0)

    def note(self, table: dict[str, int], name: str) -> None:
        table[name] = table.get(name, 0) + 1


class Sources:
    """Every source but the triggering LiDAR: the cameras (`cameras`), the other LiDARs and
    the clouds, each with its own window and mounting."""

    def __init__(self, config: FusionConfig, previous: Sources | None = None) -> None:
        self.config = config
        sources = config.sources
        # The LiDAR on `scan_topic` triggers (the `trigger` one, or the first listed).
        self.lidars = {s.name: s for s in sources.lidars if s.topic != config.scan_topic}
        self.clouds = {s.name: s for s in sources.clouds}
        self.cameras = camera_feeds(config)
        for feed in self.cameras.values():
            feed.track_ground(config.ground_estimate)
            old = None if previous is None else previous.cameras.get(feed.name)
            if old is not None:
                feed.keep_state_of(old)
        every: list[LidarSource | CloudSource] = [*self.lidars.values(), *self.clouds.values()]
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
        self.counts: SourceCounts = SourceCounts() if previous is None else previous.counts

    @property
    def names(self) -> list[str]:
        """The named sources that add to an output (every one but the triggering LiDAR)."""
        named = [s.name for s in self.config.sources.cameras]
        return [*self.lidars, *named, *self.clouds]

    def __contains__(self, name: object) -> bool:
        return name in self._state or name in self.cameras

    def camera(self, source: str | None) -> CameraFeed | None:
        """The camera `source` names; None or a name no camera has: the camera on the
        one-source `depth_topic` (None when there is none)."""
        if source is not None and source in self.cameras:
            return self.cameras[source]
        topic = self.config.depth_topic
        return next((f for f in self.cameras.values() if f.depth_topic == topic), None)

    # ------------------------------------------------------------ inputs

    def add_scan(self, name: str, scan: Scan) -> None:
        # A driver's error values (a Hokuyo's 0.0 "no return") are no readings: NaN, as the
        # triggering LiDAR's are (`normalized_ranges`), not points at the sensor's own origin.
        scan = scan.with_ranges(normalized_ranges(scan))
        self._state[name].messages.append(_Message(scan.stamp_ns, scan.frame_id, scan))

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

    def point_contributions(
        self, output: Scan, base_to_output: Transform, locator: Locator
    ) -> tuple[list[Scan], list[Scan]]:
        """(LiDAR scans, cloud scans) of the LiDARs and clouds on the output grid and stamp."""
        lidars: list[Scan] = []
        clouds: list[Scan] = []
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
            (lidars if name in self.lidars else clouds).append(scan)
        return lidars, clouds

    def _contribution(
        self,
        name: str,
        message: _Message,
        output: Scan,
        base_to_output: Transform,
        locator: Locator,
    ) -> Scan | None:
        config = self.config
        source: LidarSource | CloudSource = (
            self.lidars[name] if name in self.lidars else self.clouds[name]
        )
        mount = locator.mounting(message.frame_id, mounting_transform(source))
        motion = locator.motion_to(message.stamp_ns, output.stamp_ns, base_to_output)
        if mount is None or motion is None:
            return None
        if name in self.lidars:
            scan = locator.deskewed(message.data)  # type: ignore[arg-type]
            points = lidar_points(scan)
            return _points(
                points, mount, base_to_output, output, motion, -np.inf, np.inf, 1, np.inf
            )
        cloud = self.clouds[name]
        points = np.asarray(message.data).reshape(-1, 3)
        low = config.min_obstacle_height if cloud.min_height is None else cloud.min_height
        high = config.max_obstacle_height if cloud.max_height is None else cloud.max_height
        return _points(
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
