"""What the live node decides, without rclpy: pairing, pass-through, failures and health.

The rclpy node (`scanfuse.ros.node`) only moves CDR bytes between DDS and this
class, so every decision here is testable without DDS and the node and the bag
processor share one decode/encode path (`scanfuse.ros.messages`) and one fusion
(`FusionPipeline`).

Rules (issue 7): a scan is fused with the depth frame whose stamp is nearest its
own within `max_time_offset`, as the bag processor pairs; with `pair_wait > 0`
a scan newer than every frame received waits at most that long for a frame
stamped at or after it (that frame may be the nearer one), else it is paired
with what has arrived. The camera silent longer than `camera_timeout`, no
CameraInfo yet, or no frame near enough: the LiDAR's own bytes are published
unchanged. Malformed messages are counted, logged once per kind and dropped.
Nothing is published without a LiDAR scan.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import MessageError, ScanfuseError, TransformError
from scanfuse.pipeline import FusionPipeline
from scanfuse.ros.messages import (
    camera_from_cdr,
    check_depth_matches_camera,
    depth_from_cdr,
    frame_name,
    scan_from_cdr,
    scan_to_cdr,
    transforms_from_cdr,
    typestore,
)
from scanfuse.ros.sync import UNPAIRED, pair_nearest, seconds_to_ns
from scanfuse.ros.tf import TransformStore
from scanfuse.transforms import Extrinsics, Transform

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from scanfuse.camera import CameraModel
    from scanfuse.config import FusionConfig
    from scanfuse.ros.messages import DepthImage, RawMessage
    from scanfuse.scan import Scan

logger = logging.getLogger(__name__)

# Frames kept for pairing: at 30 Hz and max_time_offset 0.1 s about 7 are ever useful.
MAX_FRAMES = 16
WARN_EVERY_S = 5.0


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


@dataclass(frozen=True)
class Output:
    """One scan to publish: fused CDR (the LiDAR's own bytes when passed through)."""

    fused: bytes
    depth_scan: bytes | None
    received: float  # monotonic seconds the LiDAR scan arrived
    with_camera: bool


@dataclass(frozen=True)
class Health:
    """The node's state for /diagnostics."""

    level: Level
    state: State
    message: str
    values: dict[str, str]


@dataclass
class _Frame:
    stamp_ns: int
    image: DepthImage
    camera: CameraModel


@dataclass
class _Pending:
    scan: Scan
    raw: bytes
    received: float
    deadline: float


@dataclass
class _Window:
    """Counts since the last health report."""

    scans: int = 0
    paired: int = 0
    times: list[float] = field(default_factory=list)
    # Scans passed through because the camera was silent: a report covers its whole window,
    # so a gap shorter than the report period is not hidden by the timer's phase.
    silent_camera_ns: int | None = None


def _without_stamp(raw: RawMessage) -> bytes | None:
    """A message's CDR bytes less its header stamp (bytes 4-12, after the encapsulation)."""
    data = bytes(raw)
    return data[:4] + data[12:] if len(data) > 12 else None


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
        self.pair_wait = pair_wait
        self.lidar_timeout = lidar_timeout
        self.tf = TransformStore()
        self.malformed: dict[str, int] = {}
        self.published = 0
        self.passed_through = 0
        self._frames: deque[_Frame] = deque(maxlen=MAX_FRAMES)
        self._pending: deque[_Pending] = deque()
        self._camera: CameraModel | None = None
        self._camera_key: bytes | None = None
        self._last_scan: float | None = None
        self._last_depth: float | None = None
        self._started: float | None = None  # first message or health report
        self._last_warning: dict[str, float] = {}
        self._window = _Window()
        self._window_start: float | None = None
        self._extrinsics: dict[tuple[str, str], Extrinsics] = {}
        self.extrinsics_source = 'parameters'
        self.reconfigure(config)

    # ------------------------------------------------------------ configuration

    def reconfigure(self, config: FusionConfig) -> None:
        """Use a new configuration from the next scan on (ray tables and plans are rebuilt)."""
        self.config = config
        self.pipeline = FusionPipeline(config)
        self._extrinsics.clear()

    def warm_up(self) -> None:
        """Fuse one tiny synthetic frame, so compiled kernels load now and not on a live scan."""
        from scanfuse.camera import CameraModel  # noqa: PLC0415
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

    # ------------------------------------------------------------ inputs

    def on_scan(self, raw: RawMessage, now: float) -> list[Output]:
        self._note_start(now)
        try:
            scan = scan_from_cdr(raw, self.store)
        except MessageError as err:
            self._malformed('scan', err)
            return []
        self._last_scan = now
        self._window.scans += 1
        pending = _Pending(scan, bytes(raw), now, now + self.pair_wait)
        if self._should_wait(scan, now):
            self._pending.append(pending)
            return self._release(now)
        return [*self._release(now, flush=True), self._resolve(pending, now)]

    def on_depth(self, raw: RawMessage, now: float) -> list[Output]:
        self._note_start(now)
        try:
            image = depth_from_cdr(raw, self.store)
            if self._camera is not None:
                check_depth_matches_camera(image, self._camera)
        except MessageError as err:
            self._malformed('depth image', err)
            return self._release(now)
        self._last_depth = now
        if self._camera is not None:
            self._frames.append(_Frame(image.stamp_ns, image, self._camera))
        return self._release(now)

    def on_camera_info(self, raw: RawMessage, now: float) -> None:
        self._note_start(now)
        # Drivers send the same CameraInfo with every frame: only its stamp changes.
        key = _without_stamp(raw)
        if key is not None and key == self._camera_key:
            return
        try:
            camera = camera_from_cdr(raw, self.store)
        except MessageError as err:
            self._malformed('camera info', err)
            return
        self._camera_key = key
        if camera != self._camera:
            self._camera = camera
            self._frames.clear()

    def on_tf(self, raw: RawMessage, *, static: bool) -> None:
        try:
            self.tf.add_all(transforms_from_cdr(raw, self.store), static=static)
        except (MessageError, TransformError) as err:
            self._malformed('tf', err)
            return
        self._extrinsics.clear()

    def on_tick(self, now: float) -> list[Output]:
        """Scans whose wait for a newer frame is over."""
        return self._release(now)

    def next_deadline(self) -> float | None:
        """When the oldest waiting scan must be released (monotonic s), None when none waits."""
        return self._pending[0].deadline if self._pending else None

    # ------------------------------------------------------------ decisions

    def camera_alive(self, now: float) -> bool:
        return self._last_depth is not None and now - self._last_depth <= self.config.camera_timeout

    def _should_wait(self, scan: Scan, now: float) -> bool:
        if self.pair_wait <= 0.0 or self._camera is None or not self.camera_alive(now):
            return False
        return not self._frames or self._frames[-1].stamp_ns < scan.stamp_ns

    def _release(self, now: float, *, flush: bool = False) -> list[Output]:
        """Pending scans, oldest first, that have a frame after them or waited long enough."""
        out = []
        while self._pending:
            first = self._pending[0]
            newest = self._frames[-1].stamp_ns if self._frames else None
            ready = newest is not None and newest >= first.scan.stamp_ns
            if not (ready or flush or now >= first.deadline or not self.camera_alive(now)):
                break
            out.append(self._resolve(self._pending.popleft(), now))
        return out

    def _resolve(self, pending: _Pending, now: float) -> Output:
        scan = pending.scan
        if self._camera is None:
            self._warn_throttled(
                'camera info',
                now,
                f'no CameraInfo on {self.config.camera_info_topic} yet: passing the LiDAR through',
            )
            return self._pass_through(pending)
        if not self.camera_alive(now):
            self._window.silent_camera_ns = pending.scan.stamp_ns
            return self._pass_through(pending)
        stamps = np.array([frame.stamp_ns for frame in self._frames], dtype=np.int64)
        index = int(
            pair_nearest([scan.stamp_ns], stamps, seconds_to_ns(self.config.max_time_offset))[0]
        )
        if index == UNPAIRED:
            return self._pass_through(pending)
        frame = self._frames[index]
        try:
            result = self.pipeline.fuse(
                scan, frame.image.depth, frame.camera, self._extrinsics_for(scan, frame)
            )
            fused = scan_to_cdr(result.fused, self.store)
            depth_scan = (
                scan_to_cdr(result.depth_scan, self.store)
                if self.config.publish_depth_scan
                else None
            )
        except ScanfuseError as err:
            self._malformed('fusion', err)
            return self._pass_through(pending)
        self._window.paired += 1
        self._window.times.append(result.timings.total)
        self.published += 1
        return Output(fused, depth_scan, pending.received, with_camera=True)

    def _pass_through(self, pending: _Pending) -> Output:
        self.published += 1
        self.passed_through += 1
        return Output(pending.raw, None, pending.received, with_camera=False)

    def _extrinsics_for(self, scan: Scan, frame: _Frame) -> Extrinsics | None:
        """Extrinsics from TF when it relates both sensors to the base, else the parameters."""
        if not self.config.use_tf:
            self.extrinsics_source = 'parameters (use_tf is false)'
            return None
        key = (frame_name(scan.frame_id), frame_name(frame.image.frame_id or frame.camera.frame_id))
        cached = self._extrinsics.get(key)
        if cached is not None:
            return cached
        base = self.config.base_frame
        try:
            extrinsics = Extrinsics(
                base_to_laser=Transform.from_matrix(self.tf.lookup(base, key[0])),
                base_to_camera_optical=Transform.from_matrix(self.tf.lookup(base, key[1])),
            )
        except (TransformError, ScanfuseError):
            self.extrinsics_source = 'parameters (TF does not relate the sensors to the base)'
            return None
        self._extrinsics[key] = extrinsics
        self.extrinsics_source = f'TF ({base} -> {key[0]}, {key[1]})'
        return extrinsics

    # ------------------------------------------------------------ failures

    def _malformed(self, kind: str, err: ScanfuseError) -> None:
        count = self.malformed.get(kind, 0) + 1
        self.malformed[kind] = count
        if count == 1:
            logger.warning('dropped a malformed %s (further ones are only counted): %s', kind, err)

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
        camera_age = now - self._last_depth if self._last_depth is not None else float('inf')
        values = {
            'scan rate (Hz)': f'{window.scans / seconds:.2f}' if seconds else '0',
            'paired rate (Hz)': f'{window.paired / seconds:.2f}' if seconds else '0',
            'processing time p50 (ms)': f'{np.median(times_ms):.2f}' if times_ms.size else 'nan',
            'processing time max (ms)': f'{times_ms.max():.2f}' if times_ms.size else 'nan',
            'camera age (s)': f'{camera_age:.3f}',
            'published': str(self.published),
            'passed through': str(self.passed_through),
            'extrinsics': self.extrinsics_source,
            **{f'malformed {kind}': str(count) for kind, count in sorted(self.malformed.items())},
        }
        level, state, message = self._classify(now, camera_age)
        if level == Level.OK and window.silent_camera_ns is not None:
            level, state = Level.WARN, State.PASS_THROUGH
            message = (
                f'no depth image on {self.config.depth_topic} within camera_timeout for a part '
                'of the last report period: LiDAR passed through'
            )
        values['state'] = state.value
        return Health(level, state, message, values)

    def _classify(self, now: float, camera_age: float) -> tuple[Level, State, str]:
        lidar_age = now - (self._last_scan if self._last_scan is not None else self._started or now)
        if self._last_scan is None or lidar_age > self.lidar_timeout:
            what = 'no LiDAR scan yet' if self._last_scan is None else 'LiDAR silent'
            return (
                Level.ERROR,
                State.NO_LIDAR,
                f'{what} on {self.config.scan_topic} ({lidar_age:.1f} s): publishing nothing',
            )
        if self._camera is None:
            return (
                Level.WARN,
                State.NO_CAMERA_INFO,
                f'no CameraInfo on {self.config.camera_info_topic}: LiDAR passed through',
            )
        if camera_age > self.config.camera_timeout:
            return (
                Level.WARN,
                State.PASS_THROUGH,
                (
                    f'no depth image on {self.config.depth_topic} for {camera_age:.1f} s: '
                    'LiDAR passed through'
                ),
            )
        return Level.OK, State.FUSING, 'fusing'
