"""The live node's adapter, without rclpy: CDR in, scans to publish and health out.

The rclpy node (`scanfuse.ros.node`) only moves CDR bytes between DDS and this class; this
class decodes them (`scanfuse.ros.messages`, the bag processor's decoder) and feeds the one
`FusionStream`, which decides pairing, pass-through, extrinsics and motion compensation
exactly as it does for `scanfuse bag`. What is the node's own: the monotonic clock, the
CDR of pass-through scans (published unchanged), CameraInfo decoded only when it changes,
and the health it reports on /diagnostics.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import MessageError, ScanfuseError
from scanfuse.pipeline import grids_match
from scanfuse.ros.messages import (
    camera_from_cdr,
    check_depth_matches_camera,
    cloud_from_cdr,
    depth_from_cdr,
    imu_from_cdr,
    odometry_from_cdr,
    scan_from_cdr,
    scan_to_cdr,
    transforms_from_cdr,
    typestore,
)
from scanfuse.scan import normalized_ranges
from scanfuse.stream import FusionStream, Passed, StreamOutput

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from scanfuse.camera import CameraModel
    from scanfuse.config import FusionConfig
    from scanfuse.pipeline import FusionPipeline
    from scanfuse.ros.messages import RawMessage
    from scanfuse.scan import AngleGrid, Scan

logger = logging.getLogger(__name__)

WARN_EVERY_S = 5.0
# Median processing time above this share of the scan period: the node falls behind.
TOO_SLOW_SHARE = 0.8


class Level(IntEnum):
    """`diagnostic_msgs/DiagnosticStatus` levels."""

    OK = 0
    WARN = 1
    ERROR = 2


class State(str, Enum):
    """What the node does with the scans right now."""

    FUSING = 'fusing'
    PASS_THROUGH = 'pass-through (camera silent)'  # noqa: S105 - not a password
    NO_CAMERA_INFO = 'pass-through (no CameraInfo)'
    NO_LIDAR = 'no LiDAR scans: publishing nothing'
    NO_DEPTH = 'no depth images (no LiDAR): publishing nothing'
    CAMERA_UNUSABLE = 'camera input unusable'
    NO_EXTRINSICS = 'pass-through (extrinsics refused)'
    TOO_SLOW = 'processing too slow'
    MEMORY_DROPPED = 'obstacle memory dropped'
    SOURCE_MISSING = 'a named source contributes nothing'
    MOUNT_MISMATCH = 'the floor disagrees with the camera mounting'


@dataclass(frozen=True)
class Output:
    """One scan to publish: fused CDR (the LiDAR's own bytes when passed through)."""

    fused: bytes
    depth_scan: bytes | None
    received: float  # monotonic seconds the LiDAR scan arrived
    with_camera: bool
    instant: bytes | None = None  # with memory: the fused scan without it
    memory_scan: bytes | None = None  # with memory: the remembered obstacles alone


@dataclass(frozen=True)
class Health:
    """The node's state for /diagnostics."""

    level: Level
    state: State
    message: str
    values: dict[str, str]


@dataclass
class _Window:
    """What happened since the last health report (a report covers its whole window, so a
    short camera gap between two reports is not hidden by the timer's phase)."""

    scans: int = 0
    paired: int = 0
    times: list[float] = field(default_factory=list)
    stamps: list[int] = field(default_factory=list)
    passed: dict[Passed, int] = field(default_factory=dict)
    empty_depth: int = 0  # fused scans whose depth scan held no reading at all
    memory_drops: int = 0
    malformed_depth: int = 0
    # Per named source: output scans it was used in / passed over in (missing, no mounting).
    source_used: dict[str, int] = field(default_factory=dict)
    source_missed: dict[str, int] = field(default_factory=dict)


Problem = tuple[Level, State, str]


def _without_stamp(raw: RawMessage) -> bytes | None:
    """A message's CDR bytes less its header stamp (bytes 4-12, after the encapsulation)."""
    data = bytes(raw)
    return data[:4] + data[12:] if len(data) > 12 else None


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


class LiveFusion:
    """Turns incoming CDR messages (with their monotonic arrival time) into scans to publish."""

    def __init__(
        self,
        config: FusionConfig,
        *,
        pair_wait: float = 0.0,
        lidar_timeout: float = 1.0,
        store: Typestore | None = None,
    ) -> None:
        self.store = store or typestore()
        self.lidar_timeout = lidar_timeout
        self.stream: FusionStream[bytes] = FusionStream(config, pair_wait=pair_wait)
        self.published = 0
        self._camera_key: bytes | None = None
        self._last_scan: float | None = None
        self._started: float | None = None  # first message or health report
        self._last_warning: dict[str, float] = {}
        self._window = _Window()
        self._window_start: float | None = None
        self._memory_drops_reported = 0
        self._source_keys: dict[str, bytes | None] = {}  # CameraInfo of other cameras
        self._camera_info_error: str | None = None  # the last CameraInfo was unusable
        self._grid: tuple[AngleGrid, str] | None = None  # the primary LiDAR's grid and frame
        self._grid_scan: Scan | None = None  # a scan of that grid: the output it makes
        self._sources_reported: tuple[dict[str, int], dict[str, int]] = ({}, {})

    # ------------------------------------------------------------ configuration

    @property
    def config(self) -> FusionConfig:
        return self.stream.config

    @property
    def pair_wait(self) -> float:
        return self.stream.pair_wait_ns / 1e9

    @pair_wait.setter
    def pair_wait(self, seconds: float) -> None:
        self.stream.pair_wait_ns = seconds * 1e9

    @property
    def malformed(self) -> dict[str, int]:
        return self.stream.counts.malformed

    @property
    def passed_through(self) -> int:
        return self.stream.counts.passed_through

    @property
    def extrinsics_source(self) -> str:
        return self.stream.extrinsics_source

    def reconfigure(self, config: FusionConfig) -> None:
        """Use a new configuration from the next scan on (ray tables and plans are rebuilt)."""
        self.stream.reconfigure(config)

    def warm_up(self) -> None:
        """Fuse one tiny synthetic frame, so compiled kernels load now and not on a live scan."""
        from scanfuse.camera import CameraModel  # noqa: PLC0415
        from scanfuse.pipeline import FusionPipeline  # noqa: PLC0415
        from scanfuse.scan import Scan  # noqa: PLC0415

        camera = CameraModel.from_intrinsics(16, 12, 10.0, 10.0, 7.5, 5.5, frame_id='warm_up')
        scan = Scan(
            angle_min=-0.5,
            angle_max=0.5,
            angle_increment=0.1,
            range_min=0.1,
            range_max=10.0,
            ranges=np.full(11, 2.0, dtype=np.float32),
            frame_id='warm_up',
        )
        pipeline = FusionPipeline(self.config)
        pipeline.fuse(scan, np.full((12, 16), 1000, dtype=np.uint16), camera)
        pipeline.fuse(scan, np.full((12, 16), 1.0, dtype=np.float32), camera)
        if self.config.ground_estimate or self.config.imu_topic:
            self._warm_up_ground(pipeline, camera, scan)
        if self.config.sources.clouds:
            self._warm_up_clouds(scan)

    def _warm_up_ground(self, pipeline: FusionPipeline, camera: CameraModel, scan: Scan) -> None:
        """The floor's compiled parts: the fit and the profile's walk (both depth types), a
        ramp's ground under each pixel, the height tables' rebuild, and the memory's slab and
        clearing above a ramp; else the first frames of a ramp or a pitching body load them."""
        from scanfuse.convert.ground import (  # noqa: PLC0415
            GroundPlane,
            GroundProfile,
            GroundSettings,
            GroundTracker,
        )
        from scanfuse.memory import MemorySettings, ObstacleMemory, slab_points  # noqa: PLC0415
        from scanfuse.transforms import Extrinsics, Transform  # noqa: PLC0415

        mounting = Extrinsics.from_config(self.config).base_to_camera_optical
        prior = GroundPlane.of_mounting(mounting)
        tracker = GroundTracker(GroundSettings())
        for depth in (np.full((12, 16), 1000, np.uint16), np.full((12, 16), 1.0, np.float32)):
            tracker.update(depth, camera, prior)
        profile = GroundProfile(prior, np.arange(0, 16, 4), np.zeros((4, 20)), 0.15)
        tilted = GroundPlane.of_mounting(Transform.from_rpy(0.0, 0.05, 0.0) @ mounting)
        pipeline.fuse(scan, np.full((12, 16), 1000, np.uint16), camera, ground=tilted)
        pipeline.fuse(
            scan, np.full((12, 16), 1.0, np.float32), camera, ground=tilted, profile=profile
        )
        lifts = profile.slab_lifts(
            camera,
            self.config.range_max,
            self.config.min_obstacle_height,
            self.config.max_obstacle_height,
        )
        memory = ObstacleMemory(MemorySettings(2.0, 1.0, 0.05))
        for depth in (np.full((12, 16), 1000, np.uint16), np.full((12, 16), 1.0, np.float32)):
            slab = (self.config.min_obstacle_height, self.config.max_obstacle_height)
            limits = {'range_min': 0.1, 'range_max': 3.0}
            slab_points(depth, camera, mounting, slab=slab, lifts=lifts, **limits)
            memory.clear_seen(depth, camera, mounting, slab=slab, profile=profile, **limits)

    def _warm_up_clouds(self, scan: Scan) -> None:
        """Bin a tiny PointCloud2 of each coordinate type, decoded as a live one is."""
        from scanfuse.convert.cloud import points_scan  # noqa: PLC0415
        from scanfuse.motion import IDENTITY_MOTION  # noqa: PLC0415
        from scanfuse.ros.messages import cloud_from_cdr, cloud_to_cdr  # noqa: PLC0415
        from scanfuse.transforms import Transform  # noqa: PLC0415

        points = np.array([[1.0, 0.0, 0.1], [1.0, 0.1, 0.1], [1.1, 0.0, 0.1], [1.1, 0.1, 0.1]])
        for dtype in ('f4', 'f8'):
            raw = cloud_to_cdr(
                points, frame_id='warm_up', stamp_ns=0, dtype=dtype, store=self.store
            )
            cloud = cloud_from_cdr(raw, self.store)
            points_scan(
                cloud.points,
                Transform.identity(),
                Transform.identity(),
                scan.grid,
                motion=IDENTITY_MOTION,
                min_height=0.0,
                max_height=1.0,
                range_min=0.1,
                range_max=10.0,
            )

    # ------------------------------------------------------------ inputs

    def _extra(self, source: str | None) -> bool:
        """A named source not on the one-source topics (those come without a name)."""
        return source is not None

    def on_scan(self, raw: RawMessage, now: float, source: str | None = None) -> list[Output]:
        self._note_start(now)
        extra = self._extra(source)
        try:
            scan = scan_from_cdr(raw, self.store)
        except MessageError as err:
            self.stream.note_malformed(f'scan ({source})' if extra else 'scan', err)
            return []
        if extra:
            return self._add_scan(scan, raw, now, source)
        self._last_scan = now
        self._window.scans += 1
        self._window.stamps.append(scan.stamp_ns)
        if len(scan) and (
            self._grid is None
            or not (grids_match(self._grid[0], scan.grid) and self._grid[1] == scan.frame_id)
        ):
            self._grid = (scan.grid, scan.frame_id)
            self._grid_scan = scan
            self._prepare_tables()
        return self._add_scan(scan, raw, now, None)

    def _add_scan(
        self, scan: Scan, raw: RawMessage, now: float, source: str | None
    ) -> list[Output]:
        """A decoded scan into the stream; one it refuses is counted as malformed, and the
        scans released meanwhile still leave."""
        try:
            released = self.stream.add_scan(scan, bytes(raw), _ns(now), source=source)
        except ScanfuseError as err:
            self.stream.note_malformed(f'scan ({source})' if source else 'scan', err)
            released = self.stream.tick(_ns(now))
        return self._outputs(released)

    def on_depth(self, raw: RawMessage, now: float, source: str | None = None) -> list[Output]:
        self._note_start(now)
        extra = self._extra(source)
        try:
            # A view of `raw`: the pixels reach the kernel without a copy.
            image = depth_from_cdr(raw, self.store)
            if not extra and self.stream.camera is not None:
                check_depth_matches_camera(image, self.stream.camera)
        except MessageError as err:
            if extra:
                self.stream.note_malformed(f'depth image ({source})', err)
                return self._outputs(self.stream.tick(_ns(now)))
            self.stream.note_malformed('depth image', err)
            self._window.malformed_depth += 1
            return self._outputs(self.stream.tick(_ns(now)))
        # Without a LiDAR the trigger camera's frame is an output: never published as is.
        return self._outputs(
            self.stream.add_depth(
                image.stamp_ns, image.depth, _ns(now), image.frame_id, source=source, token=b''
            )
        )

    def on_camera_info(self, raw: RawMessage, now: float, source: str | None = None) -> None:
        self._note_start(now)
        extra = self._extra(source)
        # Drivers send the same CameraInfo with every frame: only its stamp changes.
        key = _without_stamp(raw)
        last = self._source_keys.get(str(source)) if extra else self._camera_key
        if key is not None and key == last:
            return
        try:
            camera = camera_from_cdr(raw, self.store)
        except MessageError as err:
            self.stream.note_malformed(f'camera info ({source})' if extra else 'camera info', err)
            if not extra:
                self._camera_info_error = str(err)
            return
        if extra:
            self._source_keys[str(source)] = key
            self.stream.add_camera_info(camera, source=source)
            return
        self._camera_key = key
        self._camera_info_error = None
        self.stream.add_camera_info(camera)
        self._prepare_tables()

    def on_cloud(self, raw: RawMessage, now: float, source: str) -> list[Output]:
        """A PointCloud2 of the named cloud source `source`."""
        self._note_start(now)
        try:
            cloud = cloud_from_cdr(raw, self.store)
            return self._outputs(
                self.stream.add_cloud(
                    cloud.stamp_ns, cloud.points, _ns(now), cloud.frame_id, source, b''
                )
            )
        except ScanfuseError as err:
            self.stream.note_malformed(f'cloud ({source})', err)
            return self._outputs(self.stream.tick(_ns(now)))

    def _prepare_tables(self) -> None:
        """Build the obstacle method's per-camera tables now, when CameraInfo (or a new LiDAR
        grid) arrives, so the first paired scan does not pay for them (issue 12): on the
        output's frame and grid (`FusionStream.prepare`)."""
        if self._grid_scan is not None:
            self.stream.prepare(self._grid_scan)

    def on_tf(self, raw: RawMessage, *, static: bool) -> None:
        try:
            transforms = transforms_from_cdr(raw, self.store)
        except ScanfuseError as err:
            self.stream.note_malformed('tf', err)
            return
        self.stream.add_transforms(transforms, static=static)

    def on_odometry(self, raw: RawMessage) -> None:
        try:
            sample = odometry_from_cdr(raw, self.store)
        except ScanfuseError as err:
            self.stream.note_malformed('odometry', err)
            return
        self.stream.add_odometry(sample.stamp_ns, sample.pose)

    def on_imu(self, raw: RawMessage) -> None:
        try:
            sample = imu_from_cdr(raw, self.store)
        except ScanfuseError as err:
            self.stream.note_malformed('imu', err)
            return
        self.stream.add_imu(sample.stamp_ns, sample.orientation, sample.frame_id)

    def on_tick(self, now: float) -> list[Output]:
        """Scans whose wait for a newer frame is over."""
        return self._outputs(self.stream.tick(_ns(now)))

    def next_deadline(self) -> float | None:
        """When the oldest waiting scan must be released (monotonic s), None when none waits."""
        deadline = self.stream.next_deadline_ns()
        return None if deadline is None else deadline / 1e9

    def camera_alive(self, now: float) -> bool:
        return self.stream.camera_alive(_ns(now))

    # ------------------------------------------------------------ outputs

    def _outputs(self, results: list[StreamOutput[bytes]]) -> list[Output]:
        return [self._encode(result) for result in results]

    def _encode(self, result: StreamOutput[bytes]) -> Output:
        self.published += 1
        received = result.arrived_ns / 1e9
        window = self._window
        if result.passed is not None:
            window.passed[result.passed] = window.passed.get(result.passed, 0) + 1
            if result.passed is Passed.NO_CAMERA_INFO:
                self._warn_throttled(
                    'camera info',
                    received,
                    f'no CameraInfo on {self.config.camera_info_topic} yet: '
                    'passing the LiDAR through',
                )
        fused = result.fused
        try:
            instant = self._instant(result) if self.stream.memory is not None else None
            memory = self._cdr(result.memory_scan)
            if fused is None:
                return Output(result.token, None, received, False, instant, memory)  # noqa: FBT003
            fused_raw = scan_to_cdr(fused, self.store)
            depth_raw = (
                scan_to_cdr(result.depth_scan, self.store)
                if self.config.publish_depth_scan and result.depth_scan is not None
                else None
            )
        except ScanfuseError as err:
            self.stream.note_malformed('fusion', err)
            return Output(result.token, None, received, with_camera=False)
        if result.with_camera:
            window.paired += 1
            if result.timings is not None:
                window.times.append(result.timings.total)
            if result.depth_scan is not None and np.isnan(result.depth_scan.ranges).all():
                window.empty_depth += 1
        return Output(fused_raw, depth_raw, received, result.with_camera, instant, memory)

    def _instant(self, result: StreamOutput[bytes]) -> bytes | None:
        """The fused scan without the memory; the LiDAR's own bytes when nothing was fused."""
        scan = result.instant if result.instant is not None else result.fused
        return result.token if scan is None else self._cdr(scan)

    def passthrough(self, raw: RawMessage) -> bytes:
        """A LiDAR scan's bytes to publish unchanged: its own when it holds no driver's
        error value (a Hokuyo's 0.0), else re-encoded with those as NaN (MessageError: it
        cannot be decoded)."""
        scan = scan_from_cdr(raw, self.store)
        ranges = normalized_ranges(scan)
        if np.array_equal(ranges, scan.ranges, equal_nan=True):
            return bytes(raw)
        return scan_to_cdr(scan.with_ranges(ranges), self.store)

    def _cdr(self, scan: Scan | None) -> bytes | None:
        return None if scan is None else scan_to_cdr(scan, self.store)

    # ------------------------------------------------------------ failures

    def _warn_throttled(self, key: str, now: float, message: str) -> None:
        last = self._last_warning.get(key)
        if last is None or now - last >= WARN_EVERY_S:
            self._last_warning[key] = now
            logger.warning(message)

    def _note_start(self, now: float) -> None:
        if self._started is None:
            self._started = now
        if self._window_start is None:
            self._window_start = now

    # ------------------------------------------------------------ health

    def health(self, now: float) -> Health:
        """State, level and the numbers of the window since the previous call."""
        if self._started is None:
            self._started = now
        window, self._window = self._window, _Window()
        start, self._window_start = self._window_start, now
        seconds = max(now - start, 1e-9) if start is not None else 0.0
        times_ms = np.array(window.times) * 1e3
        camera_age = self.stream.camera_age_s(_ns(now))
        counts = self.stream.counts
        values = {
            'scan rate (Hz)': f'{window.scans / seconds:.2f}' if seconds else '0',
            'paired rate (Hz)': f'{window.paired / seconds:.2f}' if seconds else '0',
            'processing time p50 (ms)': f'{np.median(times_ms):.2f}' if times_ms.size else 'nan',
            'processing time max (ms)': f'{times_ms.max():.2f}' if times_ms.size else 'nan',
            'camera age (s)': f'{camera_age:.3f}',
            'published': str(self.published),
            'passed through': str(counts.passed_through),
            'motion compensated': str(counts.compensated),
            'odometry from': self.stream.odometry_source or 'none yet',
            'de-skewed': str(counts.deskewed),
            'LiDAR readings on the ground driven over': (
                str(counts.lidar_on_ground) if self.stream.trail is not None else 'off'
            ),
            'LiDAR readings on the ground a camera sees': str(counts.lidar_on_seen_ground),
            'remembered points': str(len(self.stream.memory)) if self.stream.memory else 'off',
            'memory dropped': str(counts.memory_dropped),
            'memory scan matches (accepted / refused)': (
                f'{counts.drift_matched} / {counts.drift_refused}'
            ),
            'extrinsics': self.extrinsics_source,
            **{f'passed ({reason.value})': str(n) for reason, n in counts.passed.items()},
            **{f'malformed {kind}': str(count) for kind, count in sorted(counts.malformed.items())},
        }
        values.update(self._ground_values())
        window.memory_drops = counts.memory_dropped - self._memory_drops_reported
        self._memory_drops_reported = counts.memory_dropped
        values.update(self._source_values(window))
        level, state, message = self._classify(now, camera_age, window)
        values['state'] = state.value
        return Health(level, state, message, values)

    def _ground_values(self) -> dict[str, str]:
        ground = self.stream.ground
        if ground is None:
            return {'ground estimate': 'off'}
        counts = ground.counts
        values = {
            'ground estimate': (
                f'{counts.estimated} frames estimated, {counts.fell_back} fell back'
                + (f' (last: {counts.last_reason})' if counts.fell_back else '')
            ),
            'ground profile (ramps)': 'in view' if ground.profile is not None else 'none',
        }
        means = ground.mount.means()
        if means is not None:
            values['camera on the floor found'] = means[0].describe()
            values['camera as mounted'] = means[1].describe()
        return values

    def _classify(self, now: float, camera_age: float, window: _Window) -> tuple[Level, State, str]:
        """The first problem found, most severe first; OK when there is none."""
        problems = (
            self._lidar_problem(now),
            self._camera_info_problem(),
            self._extrinsics_problem(window),
            self._silence_problem(camera_age, window),
            self._usable_problem(window),
            self._memory_problem(window),
            self._mount_problem(),
            self._sources_problem(window),
            self._speed_problem(window),
        )
        return next((p for p in problems if p is not None), (Level.OK, State.FUSING, 'fusing'))

    def _lidar_problem(self, now: float) -> Problem | None:
        if not self.config.has_lidar:
            return None  # a camera-only or clouds-only robot
        lidar_age = now - (self._last_scan if self._last_scan is not None else self._started or now)
        if self._last_scan is not None and lidar_age <= self.lidar_timeout:
            return None
        what = 'no LiDAR scan yet' if self._last_scan is None else 'LiDAR silent'
        message = f'{what} on {self.config.scan_topic} ({lidar_age:.1f} s): publishing nothing'
        return Level.ERROR, State.NO_LIDAR, message

    def _camera_info_problem(self) -> Problem | None:
        if self.stream.camera is not None or not self.config.has_camera:
            return None
        topic = self.config.camera_info_topic
        if self._camera_info_error is not None:
            message = (
                f'the camera contributes nothing: the CameraInfo on {topic} is unusable '
                f'({self._camera_info_error}); LiDAR passed through'
            )
            return Level.WARN, State.CAMERA_UNUSABLE, message
        if not self.config.has_lidar:  # the camera makes every output: none without it
            message = f'no CameraInfo on {topic}: publishing nothing'
            return Level.ERROR, State.NO_CAMERA_INFO, message
        message = f'no CameraInfo on {topic}: LiDAR passed through'
        return Level.WARN, State.NO_CAMERA_INFO, message

    def _source_values(self, window: _Window) -> dict[str, str]:
        """Per named source: output scans it was used in, missing from, without mounting;
        the window's share is kept for `_sources_problem`."""
        sources = self.stream.sources
        counts = sources.counts
        used_before, missed_before = self._sources_reported
        values = {}
        for name in sources.names:
            used = counts.used.get(name, 0)
            missing = counts.missing.get(name, 0)
            no_mounting = counts.no_mounting.get(name, 0)
            window.source_used[name] = used - used_before.get(name, 0)
            window.source_missed[name] = missing + no_mounting - missed_before.get(name, 0)
            values[f'source {name}'] = f'used {used}, missing {missing}, no mounting {no_mounting}'
            if name in sources.clouds:
                values[f'source {name}'] += f', no-return points {counts.no_return.get(name, 0)}'
        self._sources_reported = (
            {name: counts.used.get(name, 0) for name in sources.names},
            {
                name: counts.missing.get(name, 0) + counts.no_mounting.get(name, 0)
                for name in sources.names
            },
        )
        return values

    def _sources_problem(self, window: _Window) -> Problem | None:
        silent = sorted(
            name
            for name, missed in window.source_missed.items()
            if missed and not window.source_used.get(name)
        )
        if not silent:
            return None
        message = (
            f'named sources {", ".join(silent)} contributed to no scan of the last period '
            '(nothing within their max_time_offset, or TF cannot place their frame): '
            'fusing what is there'
        )
        return Level.WARN, State.SOURCE_MISSING, message

    def _extrinsics_problem(self, window: _Window) -> Problem | None:
        if not window.passed.get(Passed.NO_EXTRINSICS):
            return None
        return Level.ERROR, State.NO_EXTRINSICS, self.extrinsics_source

    def _silence_problem(self, camera_age: float, window: _Window) -> Problem | None:
        config = self.config
        if not config.has_camera:
            return None
        silent_now = camera_age > config.camera_timeout
        if not (silent_now or window.passed.get(Passed.CAMERA_SILENT)):
            return None
        if window.malformed_depth:
            message = (
                f'{window.malformed_depth} malformed depth images on {config.depth_topic} '
                'in the last period: LiDAR passed through'
            )
            return Level.WARN, State.CAMERA_UNUSABLE, message
        age = (
            f'for {camera_age:.1f} s'
            if silent_now
            else 'within camera_timeout for a part of the last report period'
        )
        if not config.has_lidar:  # the camera makes every output: none without it
            message = f'no depth image on {config.depth_topic} {age}: publishing nothing'
            return Level.ERROR, State.NO_DEPTH, message
        message = f'no depth image on {config.depth_topic} {age}: LiDAR passed through'
        return Level.WARN, State.PASS_THROUGH, message

    def _usable_problem(self, window: _Window) -> Problem | None:
        unusable = window.passed.get(Passed.FUSION_FAILED, 0) + window.empty_depth
        if not unusable or window.paired > window.empty_depth:
            return None
        message = (
            f'the camera contributes nothing: {unusable} scans of the last period had no '
            'usable depth (check the CameraInfo distortion and the depth encoding)'
        )
        return Level.WARN, State.CAMERA_UNUSABLE, message

    def _memory_problem(self, window: _Window) -> Problem | None:
        if not window.memory_drops:
            return None
        message = (
            'obstacle memory dropped: odometry lost for memory_odometry_timeout or jumped '
            f'(on {self.config.odom_topic} / TF {self.config.odom_frame}); obstacles outside '
            'the camera view are forgotten'
        )
        return Level.WARN, State.MEMORY_DROPPED, message

    def _mount_problem(self) -> Problem | None:
        ground = self.stream.ground
        message = None if ground is None else ground.mount.disagreement()
        return None if message is None else (Level.WARN, State.MOUNT_MISMATCH, message)

    def _speed_problem(self, window: _Window) -> Problem | None:
        if not window.times or len(window.stamps) < 2:
            return None
        period = float(np.median(np.diff(np.sort(window.stamps)))) / 1e9
        p50 = float(np.median(window.times))
        if not (period > 0.0 and p50 > TOO_SLOW_SHARE * period):
            return None
        message = (
            f'processing too slow: {p50 * 1e3:.1f} ms per scan at a scan period of '
            f'{period * 1e3:.1f} ms (lower obstacle_min_points or the image size)'
        )
        return Level.WARN, State.TOO_SLOW, message
