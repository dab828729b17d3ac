"""`FusionStream`: the one stateful core, fed timestamped events, returning fused scans.

The bag processor, the live node and the simulator's closed loop are thin adapters that
decode messages and feed this class; every policy lives here, once:

- **Sources.** Every camera, every LiDAR but the triggering one and every cloud adds to an
  output by one rule (`scanfuse.feeds`): its message within its own `max_time_offset` of
  the output stamp, moved there through odometry, placed by its own mounting. No camera is
  special: the one-source parameters (`depth_topic`...) are one camera among the named ones.
- **Pairing.** A scan waits for the cameras: each is fused with its buffered depth frame
  whose stamp is nearest the scan's. A scan newer than a camera's every frame waits (at most
  `pair_wait` seconds of the caller's clock) for a frame of it stamped at or after the scan:
  frames come in stamp order, so once one has, no later frame can be nearer. A scan stops
  waiting for a camera that is silent (`camera_timeout`) or has no CameraInfo. Scans leave
  in the order they came: a waiting scan holds back the ones behind it, and none is ever
  dropped. LiDARs and clouds are not waited for: theirs is the freshest message.
- **Pass-through.** No camera paired (no CameraInfo, camera silent, no frame near enough,
  extrinsics refused, odometry not covering the pair, or a fusion error) and no other
  source adds a reading: the LiDAR scan leaves unchanged (`StreamOutput.fused is None`: the
  adapter publishes the LiDAR's own bytes). Each output that some camera did not pair with
  says why (`passed`, the first such camera's reason), counted per reason and logged once.
- **Extrinsics.** From TF when it relates `base_frame` to both sensors, else from the
  mounting parameters when TF knows neither sensor frame (or `use_tf` is false); when TF
  knows a sensor frame but not its way to `base_frame`, fusion is refused with a message
  naming the trees' roots (guessing the mounting then reports the floor as obstacles).
  The choice is cached and cleared only when a transform it was built from changes.
- **Motion.** With odometry (`add_odometry`, or TF `odom_frame -> base_frame`), the depth
  frame's points are moved from the camera's stamp to the scan's stamp (base at t_camera
  -> odom -> base at t_scan), and a rotating LiDAR's beams (beam i at stamp + i *
  time_increment) are de-skewed to the scan's stamp. Without odometry the stream fuses as
  if the robot stood still and says so once.
- **Malformed input** is the adapter's to detect (it decodes); it reports it with
  `note_malformed`, and the stream keeps the counts.
- **Output.** In the first LiDAR's frame and grid, or in `output_frame` on `angle_min` ..
  `angle_max` every `angle_increment`, the LiDAR re-binned from its points
  (`scanfuse.output`). With `publish_rate` the outputs come at that rate, each the freshest
  scan moved to its stamp (`_schedule`). Without a LiDAR (`scan_topic` empty) each frame of
  the triggering camera (on `depth_topic`) makes an output (`_camera_triggered`), without
  LiDAR and camera each message of the triggering cloud (`_cloud_triggered`).

The stream has no clock of its own: every call that can release scans takes `now_ns`, the
caller's clock (monotonic time in the node, log time in a bag, simulated time in the
evaluation).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field, replace
from enum import Enum
from itertools import pairwise
from typing import TYPE_CHECKING, Generic, TypeVar, cast

import numpy as np

from scanfuse.config import Method
from scanfuse.convert.cloud import lidar_points, lidar_readings
from scanfuse.convert.ground import GroundPlane, GroundProfile
from scanfuse.errors import InputError, ScanfuseError, TransformError
from scanfuse.far_confirm import confirmed, far_readings, places
from scanfuse.feeds import CameraFeed, DepthFrame, Sources
from scanfuse.fragments import FragmentAssembler
from scanfuse.frames import StampedTransform, TransformStore, frame_name
from scanfuse.fuse.deskew import deskew_scan
from scanfuse.fuse.merge import merge_scans
from scanfuse.imu import ImuHistory, base_tilt
from scanfuse.memory import (
    MemorySettings,
    ObstacleMemory,
    Placement,
    lidar_misses,
    nearest_pixels,
    slab_points,
    worth_remembering,
)
from scanfuse.motion import IDENTITY_MOTION, OdometryHistory, PlanarMotion, PlanarPose
from scanfuse.output import (
    configured_grid,
    default_grid,
    empty_scan,
    rebinned_lidar,
    within_limits,
)
from scanfuse.pipeline import StageTimings
from scanfuse.scan import TWO_PI, check_scan_limits, full_circle, normalized_ranges
from scanfuse.scan_matching import DriftCorrection
from scanfuse.seen_ground import on_seen_ground
from scanfuse.trail import GroundTrail
from scanfuse.transforms import BODY_TO_OPTICAL, Extrinsics, Transform

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.config import FusionConfig
    from scanfuse.convert.ground import GroundTracker
    from scanfuse.pipeline import FusionPipeline
    from scanfuse.scan import AngleGrid, Scan

    F64 = npt.NDArray[np.float64]
    Mask = npt.NDArray[np.bool_]

logger = logging.getLogger(__name__)

T = TypeVar('T')

NANOSECONDS = 1_000_000_000
# Pixels of one depth frame a memory cell must hold to be remembered (`_add_slab`).
MEMORY_CELL_PIXELS = 3
# A slab pixel is remembered only when both its horizontal neighbours' depths lie within
# this share of its own: the D435's specified depth RMS error (2 % at 2 m). A pixel on an
# obstacle's outline, or one that stereo noise threw back along its ray, fails it; seen
# later from beside the obstacle it would stand in the free slot next to it. The live scan
# still uses every pixel.
MEMORY_NEIGHBOUR_AGREEMENT = 0.02
# A remembered point the LiDAR sees (its reading no farther than the point by this much,
# metres and share of the range: the evaluation's tolerance) is not kept: `unseen_by`.
LIDAR_SEES_MARGIN = (0.05, 0.02)
# A camera's slab reading is remembered as the pixel of its frame that stands for it: in its
# slot, within this many metres of its range (`_add_pixels_for`).
READING_PIXEL_WITHIN = 0.05
# Slower than this between two scans (m/s, rad/s) the robot stands still: with
# `memory_ages_while_stopped` false the memory does not age then (`_age_while_moving`).
# Far above a standing robot's odometry noise, far below any commanded motion.
STILL_SPEED = 0.01
STILL_TURN_RATE = 0.02
# Beams of a sweep whose motion is found from odometry; the rest are interpolated.
DESKEW_SAMPLES = 9
# Scans kept for `publish_rate`: only the freshest within max_time_offset of a stamp is used.
RATE_SCANS = 8
# Scans of the memory's path kept (`_move_remembered`): 5 minutes of a 10 Hz LiDAR.
MEMORY_PATH_SCANS = 3000


def seconds_to_ns(seconds: float) -> int:
    return round(seconds * NANOSECONDS)


def plane_tilt(tilt: Transform, base_to_laser: Transform) -> float:
    """Radians between the plane of a LiDAR mounted at `base_to_laser` and level, the base
    tilted by `tilt` (an IMU's roll and pitch)."""
    rotation = tilt.rotation_matrix @ base_to_laser.rotation_matrix
    # The LiDAR's axis against gravity; a LiDAR mounted upside down sweeps the same plane.
    return math.acos(min(1.0, abs(float(rotation[2, 2]))))


def _slab_readings(camera: _Seen, depth_scan: Scan) -> Mask:
    """The slots where `depth_scan` takes `camera`'s reading of the collision slab (none for
    a camera without slab readings: the row method).

    The memory takes such a reading as the pixel that stands for it (`_add_pixels_for`),
    not as the reading: that is the nearest cluster of its slot's pixels set on the slot's
    centre line, so the edge of a box that only grazes a slot stood beside the box (2.4 cm
    at 1.5 m in 2 degree slots), and seen later from beside it filled a slot the box does not
    reach. A drop-off's edge (no slab pixels: the floor is missing there) and a point
    cloud's reading are remembered as readings.
    """
    if camera.depth_scan is None or camera.slab_slots is None:
        return np.zeros(len(depth_scan), dtype=np.bool_)
    with np.errstate(invalid='ignore'):  # False against NaN: no reading
        taken: Mask = camera.slab_slots & (camera.depth_scan.ranges <= depth_scan.ranges)
    return taken


class Passed(str, Enum):
    """Why a scan left without the camera."""

    NO_CAMERA_INFO = 'no CameraInfo yet'
    CAMERA_SILENT = 'camera silent'
    NO_FRAME_NEAR = 'no depth frame within max_time_offset'
    NO_EXTRINSICS = 'TF does not relate the sensors to base_frame'
    NO_MOTION = 'odometry does not cover the pair'
    FUSION_FAILED = 'fusion failed'


class Compensation(str, Enum):
    """How the depth frame was brought to the scan's stamp."""

    OFF = 'off (motion_compensation is false)'
    NO_ODOMETRY = 'none (no odometry)'
    COMPENSATED = 'compensated through odometry'


@dataclass(frozen=True)
class StreamOutput(Generic[T]):
    """One scan leaving the stream, in arrival order.

    `fused` None: publish the LiDAR scan unchanged (`token` is the adapter's, e.g. its
    bytes). `lidar` is the LiDAR scan used (de-skewed when `deskewed`).
    """

    token: T
    lidar: Scan
    fused: Scan | None
    depth_scan: Scan | None
    arrived_ns: int
    passed: Passed | None = None
    depth_stamp_ns: int | None = None
    compensation: Compensation = Compensation.NO_ODOMETRY
    deskewed: bool = False
    timings: StageTimings | None = None
    instant: Scan | None = None  # with memory on: `fused` before the memory was merged
    memory_scan: Scan | None = None  # the remembered obstacles alone, on the LiDAR's grid
    # Every LiDAR's readings on `lidar`'s grid (None: `lidar` alone): what no camera memory
    # needs to hold, since some LiDAR sees it from where the robot is now.
    lidars: Scan | None = None

    @property
    def with_camera(self) -> bool:
        return self.passed is None

    @property
    def every_lidar(self) -> Scan:
        return self.lidar if self.lidars is None else self.lidars


@dataclass
class StreamCounts:
    """What the stream has seen and done since it was made."""

    scans: int = 0
    depth_frames: int = 0
    fused: int = 0
    compensated: int = 0
    deskewed: int = 0
    remembered: int = 0  # output scans the memory added to
    memory_cleared: int = 0  # remembered points the camera saw free
    memory_dropped: int = 0  # times the memory was dropped (odometry lost or jumped)
    drift_matched: int = 0  # LiDAR scans whose match corrected the memory's odometry
    drift_refused: int = 0  # matches refused (the memory followed odometry alone)
    odometry_ignored: int = 0  # samples of a second odometry source (see `add_odometry`)
    passed: dict[Passed, int] = field(default_factory=dict)
    malformed: dict[str, int] = field(default_factory=dict)
    peak_frames: int = 0
    imu_missed: int = 0  # depth frames with no IMU sample near them, once an IMU was heard
    lidar_on_ground: int = 0  # LiDAR readings dropped as the ground driven over (`trail`)
    lidar_on_seen_ground: int = 0  # ... as the ground a camera sees (`seen_ground`)

    @property
    def passed_through(self) -> int:
        return sum(self.passed.values())


@dataclass
class _Pending(Generic[T]):
    scan: Scan
    token: T
    arrived_ns: int
    deadline_ns: float
    assembled: bool = False  # made of fragments: no single message's bytes stand for it
    # Already in the output frame and grid (a fixed rate's scan moved to its stamp), and
    # where that frame lies on the base; None: the LiDAR's scan as it came.
    base_to_output: Transform | None = None


@dataclass(frozen=True)
class _Seen:
    """What one camera gave an output: its scan on the output grid and the frame it came
    from, or why it gave none (`reason`)."""

    feed: CameraFeed
    reason: Passed | None = None
    frame: DepthFrame | None = None
    depth_scan: Scan | None = None
    extrinsics: Extrinsics | None = None  # the mounting on the floor found (memory's slab)
    compensation: Compensation = Compensation.OFF
    timings: StageTimings | None = None
    slab_slots: Mask | None = None  # `FusedResult.slab_slots`
    mount: Transform | None = None  # the camera's optical frame on the base, as mounted


@dataclass(frozen=True)
class OutputLayout:
    """The frame and grid of an output scan, where the frame lies on the base, and the
    first LiDAR's own scan when it is already that output (None: it is re-binned)."""

    grid: AngleGrid
    frame: str
    base_to_output: Transform
    own: Scan | None = None


@dataclass(frozen=True)
class ExtrinsicsChoice:
    """The extrinsics used for a pair of sensor frames and where they came from."""

    extrinsics: Extrinsics | None  # None: refused (see `source`)
    source: str
    frames: frozenset[str] = frozenset()  # TF child frames it was built from


class FusionStream(Generic[T]):
    """Pairs, compensates and fuses; see the module docstring for every rule."""

    def __init__(
        self,
        config: FusionConfig,
        *,
        pair_wait: float = 0.0,
        release_when_silent: bool = True,
        on_output: Callable[[StreamOutput[T]], None] | None = None,
    ) -> None:
        """`pair_wait`: seconds a scan waits for a frame after it. `release_when_silent`:
        a silent camera ends the wait at once (live); a recording, where a late frame may
        still come, waits the whole `pair_wait`. `on_output` is handed every scan that
        leaves, whichever call released it (`add_scan`, `add_depth`, `tick`, `finish`...):
        the one place to collect output that cannot miss any."""
        self.on_output = on_output
        if not pair_wait >= 0.0:
            msg = f'pair_wait must be >= 0 s (math.inf: wait for the next frame), got {pair_wait}'
            raise InputError(msg)
        self.pair_wait_ns: float = pair_wait * NANOSECONDS
        self.release_when_silent = release_when_silent
        self.tf = TransformStore()
        self.counts = StreamCounts()
        self._pending: deque[_Pending[T]] = deque()
        self._started_ns: int | None = None  # first scan or frame: the cameras' grace starts
        self._newest_scan_ns: int | None = None
        self._warned: set[str] = set()
        self._extrinsics: dict[tuple[str, str, str], ExtrinsicsChoice] = {}
        self._extrinsics_key: tuple[str, str, str] | None = None  # the choice made last
        self.extrinsics_source = 'parameters (no scan fused yet)'
        self.odometry = OdometryHistory()
        self.imu = ImuHistory()
        self.odometry_source: str | None = None  # the odometry topic or TF, whichever came first
        self.memory: ObstacleMemory | None = None
        self._memory_segment: int | None = None  # odometry segment the points belong to
        # Where the memory's frame lies in odometry's: wheel odometry's drift undone by
        # matching LiDAR scans (`memory_scan_matching`); every pose the memory uses is C P.
        self.drift = DriftCorrection()
        # Per scan the memory was placed for: its stamp, the memory's clock and the base's
        # odometry pose then (`_move_remembered`).
        self._memory_path: deque[tuple[int, int, PlanarPose]] = deque(maxlen=MEMORY_PATH_SCANS)
        self._memory_placed_ns: int | None = None  # last scan the memory could be placed for
        self._memory_motion: tuple[int, PlanarPose] | None = None  # last scan's stamp, pose
        # Per camera, the slab pixels its latest frame gave the memory (that frame's stamp,
        # odometry frame): what stands for its readings (`_add_pixels_for`).
        self._slab_points: dict[str, tuple[int, F64, F64]] = {}
        self.trail: GroundTrail | None = None  # `ground_trail`: the ground driven over
        self.assembler: FragmentAssembler[T] | None = None
        # `publish_rate`: the first LiDAR's recent scans, and the next output stamp.
        self._rate_scans: deque[tuple[Scan, T]] = deque(maxlen=RATE_SCANS)
        self._next_output_ns: int | None = None
        self.reconfigure(config)

    # ------------------------------------------------------------ configuration

    def reconfigure(self, config: FusionConfig) -> None:
        """Use `config` from the next scan on (tables are rebuilt, odometry limits reset).

        Everything new is built before anything is changed: a configuration refused here
        (ScanfuseError) leaves the stream as it was.
        """
        # Every camera gets its own section's settings, pipeline and floor; what a camera
        # has received (and learnt of the floor while its settings hold) stays.
        sources = Sources(config, getattr(self, 'sources', None))
        parameters = Extrinsics.from_config(config)
        settings = MemorySettings(config.memory_radius, config.memory_time, config.memory_cell)
        previous = getattr(self, 'config', None)
        if previous is not None and previous.memory_scan_matching != config.memory_scan_matching:
            # The remembered points lie in the corrected frame or odometry's: not in the other.
            self._drop_memory('memory_scan_matching changed')
        self.config = config
        self._parameters = parameters
        self._camera_timeout_ns = seconds_to_ns(config.camera_timeout)
        self._period_ns = round(1e9 / config.publish_rate) if config.publish_rate > 0 else 0
        lidars = config.sources.lidars
        own = lidars[0].max_time_offset if lidars else None
        # How old a scan a fixed-rate output may move to its stamp (its bounded extrapolation).
        self._scan_age_ns = seconds_to_ns(config.max_time_offset if own is None else own)
        # Odometry that has arrived stays; only its extrapolation limit follows the config.
        self.odometry.max_extrapolation_ns = seconds_to_ns(config.max_odometry_extrapolation)
        self._extrinsics.clear()
        for feed in sources.cameras.values():
            feed.ground_frame_ns = None
        self.sources: Sources = sources  # every camera, other LiDAR and cloud
        self._reassemble(config)
        if not (config.ground_trail and config.method is Method.OBSTACLE):
            self.trail = None
        elif self.trail is None:
            self.trail = GroundTrail()
        if not config.memory:
            self.memory = None
            self.drift.reset()
        elif (
            self.memory is None
            or self.memory.settings.side != settings.side
            or (self.memory.settings.cell != settings.cell)
        ):
            self.memory = ObstacleMemory(settings)  # a new cell size or radius starts afresh
            self._memory_segment = None
        else:
            self.memory.settings = settings  # what is remembered stays

    def _reassemble(self, config: FusionConfig) -> None:
        """Keep the fragment assembler (and the revolution it learned: the reading count
        must not change) while its settings hold; a revolution begun when they change or
        assembly stops joins the waiting scans, never lost."""
        old = self.assembler
        keep = (
            config.assemble_fragments
            and old is not None
            and old.timeout_ns == round(config.fragment_timeout * 1e9)
        )
        if keep:
            return
        if old is not None:
            arrived = self._pending[-1].arrived_ns if self._pending else self._newest_scan_ns
            for revolution, token in old.flush():
                self._admit(revolution, token, arrived or 0, assembled=True)
        self.assembler = (
            FragmentAssembler(config.fragment_timeout) if config.assemble_fragments else None
        )

    # ------------------------------------------------------------ inputs

    def add_camera_info(self, camera: CameraModel, source: str | None = None) -> None:
        """A (new) calibration of the camera `source` names (None: the one on
        `depth_topic`): its frames of the old one are dropped."""
        feed = self.sources.camera(source)
        if feed is not None:
            feed.add_camera_info(camera)

    def add_depth(
        self,
        stamp_ns: int,
        depth: npt.NDArray[np.generic],
        now_ns: int,
        frame_id: str = '',
        source: str | None = None,
        token: T | None = None,
    ) -> list[StreamOutput[T]]:
        """A depth image stamped `stamp_ns` (exposure time), arrived at `now_ns`, of the
        camera `source` names (None: the one on `depth_topic`).

        Without a LiDAR (`scan_topic` empty) each frame of the camera on `depth_topic` (the
        trigger) makes an output scan at its own stamp (`_camera_triggered`); `token` comes
        back with it."""
        feed = self.sources.camera(source)
        if feed is None:
            return self._release(now_ns)
        if feed.model is None:
            self._warn_once(
                f'depth before camera info {feed.name}',
                f'depth images before any CameraInfo on {feed.camera_info_topic} are dropped',
            )
            return self._release(now_ns)
        try:
            frame = feed.add_depth(stamp_ns, depth, frame_id, now_ns)
        except ScanfuseError as err:
            self.note_malformed('depth image' if source is None else f'depth image ({source})', err)
            return self._release(now_ns)
        if self._started_ns is None:
            self._started_ns = now_ns
        self.counts.depth_frames += 1
        self.counts.peak_frames = max(self.counts.peak_frames, len(feed.frames))
        if not self.config.has_lidar and feed is self.sources.camera(None):
            return self._camera_triggered(feed, frame, now_ns, cast('T', token))
        return self._release(now_ns)

    def add_scan(
        self, scan: Scan, token: T, now_ns: int, source: str | None = None
    ) -> list[StreamOutput[T]]:
        """A LiDAR scan arrived at `now_ns`; `token` comes back with its output.

        Scans of the first LiDAR (`source` None or its name) make output scans; those of
        other named LiDARs are kept for them. A scan with no readings is refused (InputError):
        it has no grid to fuse onto, nothing to pass through. So is one whose numbers would
        size allocations without bound (`check_scan_limits`); the adapter counts both as
        malformed (`note_malformed`).
        """
        topic = source or self.config.scan_topic
        if scan.ranges.size == 0:
            msg = (
                f'LiDAR scan on {topic} has no readings (angle_min {scan.angle_min:g}, '
                f'angle_max {scan.angle_max:g}): nothing to fuse, skipped; check the driver'
            )
            raise InputError(msg)
        try:
            check_scan_limits(scan)
        except InputError as err:
            msg = f'LiDAR scan on {topic} skipped: {err}'
            raise InputError(msg) from err
        if source is not None and source in self.sources.lidars:
            self.sources.add_scan(source, scan)
            return self._release(now_ns)
        if self.assembler is None:
            return self._enqueue(scan, token, now_ns, assembled=False)
        out = []
        for revolution, last_token in self.assembler.add(scan, token):
            out += self._enqueue(revolution, last_token, now_ns, assembled=True)
        return out or self._release(now_ns)

    def _enqueue(
        self, scan: Scan, token: T, now_ns: int, *, assembled: bool
    ) -> list[StreamOutput[T]]:
        self._admit(scan, token, now_ns, assembled=assembled)
        return self._release(now_ns)

    def _admit(self, scan: Scan, token: T, now_ns: int, *, assembled: bool) -> None:
        """`scan` joins the scans waiting for their depth frame."""
        self.counts.scans += 1
        if self._started_ns is None:
            self._started_ns = now_ns
        if self._newest_scan_ns is not None and scan.stamp_ns < self._newest_scan_ns:
            self._warn_once(
                'scan stamps backwards',
                f'LiDAR scan stamps went backwards on {self.config.scan_topic} '
                f'({(self._newest_scan_ns - scan.stamp_ns) / 1e9:.3f} s): each is still fused '
                'with the frame nearest its own stamp, in arrival order',
            )
        self._newest_scan_ns = max(scan.stamp_ns, self._newest_scan_ns or scan.stamp_ns)
        if self._period_ns:
            self._rate_scans.append((scan, token))  # outputs at the rate's stamps: `_schedule`
            return
        self._pending.append(
            _Pending(scan, token, now_ns, now_ns + self.pair_wait_ns, assembled=assembled)
        )

    def add_cloud(
        self,
        stamp_ns: int,
        points: npt.NDArray[np.floating],
        now_ns: int,
        frame_id: str,
        source: str,
        token: T | None = None,
    ) -> list[StreamOutput[T]]:
        """The x, y, z (N x 3, sensor frame) of a named point-cloud source.

        With neither LiDAR nor camera each cloud of the first named cloud makes an output
        scan at its stamp (`_cloud_triggered`); `token` comes back with it."""
        if source not in self.sources.clouds:
            msg = f'no cloud source named {source!r}; clouds: {", ".join(self.sources.clouds)}'
            raise InputError(msg)
        points = np.asarray(points)
        if points.ndim != 2 or points.shape[1] != 3 or points.dtype.kind not in 'fiu':
            msg = (
                f'cloud {source!r}: points must be an N x 3 array of real x, y, z (metres), got '
                f'shape {points.shape} of {points.dtype}; pass only the x, y, z columns'
            )
            raise InputError(msg)
        self.sources.add_cloud(source, stamp_ns, points, frame_id)
        config = self.config
        if not (config.has_lidar or config.has_camera) and source == config.sources.clouds[0].name:
            return self._cloud_triggered(stamp_ns, now_ns, cast('T', token))
        return self._release(now_ns)

    def add_imu(
        self, stamp_ns: int, orientation: tuple[float, float, float, float], frame_id: str = ''
    ) -> None:
        """An IMU's orientation (sensor_msgs/Imu, x y z w) at `stamp_ns`: the base's pitch
        and roll then (`imu`). Its frame is placed on the base by TF (the base frame itself
        when empty); one TF cannot place, or a quaternion that is not a unit one, is
        counted as malformed."""
        base_to_imu: Transform | None = Transform()
        if frame_name(frame_id) not in ('', frame_name(self.config.base_frame)):
            base_to_imu = self.mounting(frame_id, Transform())
        try:
            if base_to_imu is None:
                msg = f'TF has no path from {self.config.base_frame} to the IMU frame {frame_id}'
                raise TransformError(msg)
            tilt = base_tilt(orientation, base_to_imu)
        except ScanfuseError as err:
            self.note_malformed('imu', err)
            return
        self.imu.add(stamp_ns, tilt)

    def add_odometry(self, stamp_ns: int, pose: PlanarPose, *, source: str | None = None) -> None:
        """The base's pose in the odometry frame at `stamp_ns` (nav_msgs/Odometry or TF).

        `source` names where it came from (None: the odometry topic). Odometry is taken from
        the first source that delivers; another's samples are ignored: a robot publishing
        both /odom and TF odom -> base_link delivers one estimate twice, and the two streams
        arrive interleaved out of stamp order.
        """
        name = source or self.config.odom_topic
        if self.odometry_source is None:
            self.odometry_source = name
        elif name != self.odometry_source:
            self.counts.odometry_ignored += 1
            if f'odometry ignored {name}' not in self._warned:
                self._warned.add(f'odometry ignored {name}')
                logger.info(
                    'odometry taken from %s; %s carries it too and is ignored',
                    self.odometry_source,
                    name,
                )
            return
        before = self.odometry.breaks, self.odometry.rejected, self.odometry.out_of_order
        self.odometry.add(stamp_ns, pose)
        after = self.odometry.breaks, self.odometry.rejected, self.odometry.out_of_order
        for kind, old, new in zip(
            ('jump or gap', 'non-finite', 'out of order'), before, after, strict=True
        ):
            if new > old:
                self._warn_once(
                    f'odometry {kind}',
                    f'odometry {kind} at {stamp_ns / 1e9:.3f} s: no motion is compensated across '
                    'it (further ones are only counted)',
                )

    def add_transforms(
        self, transforms: Iterable[StampedTransform], *, static: bool, odometry: bool = True
    ) -> None:
        """TF: mounting poses, and `odom_frame -> base_frame` as odometry.

        `odometry=False` skips odometry transforms altogether (a pass over a whole recording
        for its mounting poses, before its messages are fed in order).
        """
        odom, base = frame_name(self.config.odom_frame), frame_name(self.config.base_frame)
        mounting = []
        for transform in transforms:
            if not static and transform.parent == odom and transform.child == base:
                if odometry:
                    self.add_odometry(
                        transform.stamp_ns, _planar(transform), source=f'TF {odom} -> {base}'
                    )
            else:
                mounting.append(transform)
        try:
            changed = self.tf.add_all(mounting, static=static)
        except TransformError as err:
            self.note_malformed('tf', err)
            return
        if changed:
            stale = [
                key
                for key, choice in self._extrinsics.items()
                if choice.frames & changed or not choice.frames
            ]
            for key in stale:
                del self._extrinsics[key]
            if self._extrinsics_key in stale:
                # What the node reports must not name a TF tree that has changed since
                # (a choice made before /tf_static arrived said "TF has neither frame").
                self.extrinsics_for(*self._extrinsics_key)

    def tick(self, now_ns: int) -> list[StreamOutput[T]]:
        """Scans whose wait is over by `now_ns`."""
        return self._release(now_ns)

    def finish(self) -> list[StreamOutput[T]]:
        """Every scan still waiting (end of a recording), fused with what has arrived; with
        fragment assembly, the revolution begun too (padded with NaN once one is known)."""
        if self.assembler is not None:
            arrived = self._pending[-1].arrived_ns if self._pending else self._newest_scan_ns
            for revolution, token in self.assembler.flush():
                self._admit(revolution, token, arrived or 0, assembled=True)
        self._schedule(self._newest_scan_ns or 0)
        out = []
        while self._pending:
            pending = self._pending.popleft()
            out.append(self._settle(pending))
        return out

    def next_deadline_ns(self) -> float | None:
        """When the oldest waiting scan is released at the latest (caller's clock)."""
        return self._pending[0].deadline_ns if self._pending else None

    def note_malformed(self, kind: str, err: Exception) -> None:
        """An input the adapter could not decode (or the stream could not use): counted."""
        count = self.counts.malformed.get(kind, 0) + 1
        self.counts.malformed[kind] = count
        if count == 1:
            logger.warning('dropped a malformed %s (further ones are only counted): %s', kind, err)

    # ------------------------------------------------------------ state

    def camera_alive(self, now_ns: int, source: str | None = None) -> bool:
        """The camera `source` names (None: the one on `depth_topic`) sent a depth frame
        within camera_timeout (at start-up: the stream began then)."""
        feed = self.sources.camera(source)
        return feed is not None and self._alive(feed, now_ns)

    def _alive(self, feed: CameraFeed, now_ns: int) -> bool:
        last = feed.last_arrival_ns if feed.last_arrival_ns is not None else self._started_ns
        return last is not None and now_ns - last <= self._camera_timeout_ns

    def camera_age_s(self, now_ns: int, source: str | None = None) -> float:
        feed = self.sources.camera(source)
        if feed is None or feed.last_arrival_ns is None:
            return math.inf
        return (now_ns - feed.last_arrival_ns) / 1e9

    @property
    def camera(self) -> CameraModel | None:
        """The calibration of the camera on `depth_topic` (the one-source shorthand)."""
        feed = self.sources.camera(None)
        return None if feed is None else feed.model

    @property
    def pipeline(self) -> FusionPipeline | None:
        """The pipeline of the camera on `depth_topic` (the one-source shorthand)."""
        feed = self.sources.camera(None)
        return None if feed is None else feed.pipeline

    @property
    def ground(self) -> GroundTracker | None:
        """The floor of the camera on `depth_topic` (the one-source shorthand)."""
        feed = self.sources.camera(None)
        return None if feed is None else feed.ground

    @property
    def waiting(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------ pairing

    def _release(self, now_ns: int) -> list[StreamOutput[T]]:
        self._schedule(now_ns)
        out = []
        while self._pending and self._ready(self._pending[0], now_ns):
            out.append(self._settle(self._pending.popleft()))
        self._prune_frames()
        return out

    # ------------------------------------------------------------ fixed rate

    def _schedule(self, now_ns: int) -> None:
        """With `publish_rate`: an output for every stamp k / publish_rate that the newest
        scan or odometry has reached, made of the freshest scan at most `_scan_age_ns` before
        it, moved there (`_moved_to`) and then waiting for the other sources as a scan
        does. A stamp with no such scan, or that odometry cannot reach, is skipped."""
        if not self._period_ns or not self._rate_scans:
            return
        period = self._period_ns
        reach = max(self._rate_scans[-1][0].stamp_ns, self.odometry.newest_ns or 0)
        first = self._next_output_ns
        if first is None or reach - first > self._scan_age_ns + period:
            # The first stamp, or after a gap: none older than a scan could still serve.
            earliest = min(scan.stamp_ns for scan, _ in self._rate_scans)
            first = max(earliest, reach - self._scan_age_ns - period)
            first = -(-first // period) * period
        stamp = first
        while stamp <= reach:
            fresh = [
                (scan, token)
                for scan, token in self._rate_scans
                if 0 <= stamp - scan.stamp_ns <= self._scan_age_ns
            ]
            if fresh:
                scan, token = max(fresh, key=lambda item: item[0].stamp_ns)
                moved = self._moved_to(scan, stamp)
                if moved is not None:
                    deadline = now_ns + self.pair_wait_ns
                    # Published anew (`assembled`): no received message's bytes stand for it.
                    self._pending.append(
                        _Pending(
                            moved[0], token, now_ns, deadline, assembled=True,
                            base_to_output=moved[1],
                        )
                    )  # fmt: skip
            stamp += period
        self._next_output_ns = stamp

    def _moved_to(self, scan: Scan, stamp_ns: int) -> tuple[Scan, Transform] | None:
        """`scan` (de-skewed) in the output frame and grid, moved from its stamp to
        `stamp_ns` through odometry; None when odometry does not cover the move."""
        lidar = self._off_the_trail(self._deskew(scan)[0], advance=True)
        try:
            layout = self._layout(lidar)
        except ScanfuseError as err:
            self.note_malformed('scan', err)
            return None
        base_to_output = layout.base_to_output
        motion, _ = self._motion(lidar.stamp_ns, stamp_ns, base_to_output)
        if motion is None:
            self.counts.passed[Passed.NO_MOTION] = self.counts.passed.get(Passed.NO_MOTION, 0) + 1
            return None
        base_to_laser = self.base_to_laser(lidar.frame_id)
        moved = rebinned_lidar(
            lidar, base_to_laser, base_to_output, layout.grid, layout.frame, motion=motion,
            stamp_ns=stamp_ns,
        )  # fmt: skip
        return moved, base_to_output

    def _ready(self, pending: _Pending[T], now_ns: int) -> bool:
        """Every calibrated camera has a frame at or after the scan's stamp (no later one
        can be nearer), is silent (`release_when_silent`), or the wait is over."""
        for feed in self.sources.cameras.values():
            if feed.model is None or feed.has_frame_from(pending.scan.stamp_ns):
                continue
            if self.release_when_silent and not self._alive(feed, now_ns):
                continue
            if now_ns < pending.deadline_ns:
                return False
        return True

    def _prune_frames(self) -> None:
        """Frames no waiting or future scan can pair with (scans come in stamp order)."""
        if self._newest_scan_ns is None:
            return
        oldest = self._pending[0].scan.stamp_ns if self._pending else self._newest_scan_ns
        for feed in self.sources.cameras.values():
            feed.prune(oldest)

    # ------------------------------------------------------------ one scan

    def _settle(self, pending: _Pending[T]) -> StreamOutput[T]:
        """Every output leaves through here: handed to `on_output` and returned."""
        output = self._settle_one(pending)
        if self.on_output is not None:
            self.on_output(output)
        return output

    def _settle_one(self, pending: _Pending[T]) -> StreamOutput[T]:
        """`_resolve`; a scan whose arithmetic fails is counted as malformed and passes
        through alone, so the scans released with it still leave."""
        try:
            return self._resolve(pending)
        except (ScanfuseError, ArithmeticError, ValueError) as err:
            self.note_malformed('scan', err)
            self.counts.passed[Passed.FUSION_FAILED] = (
                self.counts.passed.get(Passed.FUSION_FAILED, 0) + 1
            )
            clean = _without_error_values(pending.scan)
            return StreamOutput(
                token=pending.token,
                lidar=clean,
                fused=clean if clean is not pending.scan or pending.assembled else None,
                depth_scan=None,
                arrived_ns=pending.arrived_ns,
                passed=Passed.FUSION_FAILED,
            )

    def _resolve(self, pending: _Pending[T]) -> StreamOutput[T]:
        scan = pending.scan
        swept = None  # the LiDAR's scan as its sweep measured it (None: moved to a stamp)
        if pending.base_to_output is not None:  # moved to a fixed rate's stamp already
            lidar, deskewed, base_to_output = scan, False, pending.base_to_output
        else:
            swept = scan
            lidar, deskewed = self._deskew(scan)
            lidar, base_to_output = self._to_output(self._off_the_trail(lidar, advance=True))
        arrived = pending.arrived_ns
        seen = [
            self._camera_contribution(feed, lidar, base_to_output, arrived, scan.frame_id)
            for feed in self.sources.cameras.values()
        ]
        if not any(s.reason is None for s in seen):
            # No camera adds to it: the LiDAR as it came, its own bytes when nothing else does.
            # A driver's error values (a Hokuyo's 0.0) are published as NaN, as a fused scan's.
            clean = _without_error_values(lidar)
            fused = clean if clean is not pending.scan or pending.assembled else None
            return self._assemble(
                pending.token, pending.arrived_ns, seen, base_to_output,
                lidar=clean, fused=fused, deskewed=deskewed, swept=swept,
            )  # fmt: skip
        lidar = self._off_the_seen_ground(lidar, seen, base_to_output, swept)
        return self._assemble(
            pending.token, pending.arrived_ns, seen, base_to_output,
            lidar=lidar, fused=lidar, deskewed=deskewed, swept=swept,
        )  # fmt: skip

    def _assemble(
        self,
        token: T,
        arrived_ns: int,
        seen: list[_Seen],
        base_to_output: Transform,
        *,
        lidar: Scan,
        fused: Scan | None,
        depth_scan: Scan | None = None,
        deskewed: bool = False,
        swept: Scan | None = None,
    ) -> StreamOutput[T]:
        """The output: `fused` (None: `lidar`'s own bytes) with every camera that paired
        merged into it, then the other LiDARs and the clouds (`_with_sources`), then the
        memory (`_remember`). `passed`: why a camera did not pair (the first such, in order).
        `swept`: the first LiDAR's scan as measured, whose sweep times its beams."""
        paired = [s for s in seen if s.reason is None]
        reason = next((s.reason for s in seen if s.reason is not None), None)
        if reason is not None:
            self.counts.passed[reason] = self.counts.passed.get(reason, 0) + 1
        elif paired:
            self.counts.fused += 1
        first = paired[0] if paired else None
        if first is not None and first.compensation is Compensation.COMPENSATED:
            self.counts.compensated += 1
        for camera in paired:
            if camera.depth_scan is None:
                continue  # the trigger camera's own row scan: the output already
            scan = camera.depth_scan
            fused = merge_scans(lidar if fused is None else fused, scan)
            depth_scan = scan if depth_scan is None else merge_scans(depth_scan, scan)
        output = StreamOutput(
            token=token,
            lidar=lidar,
            fused=fused,
            depth_scan=depth_scan,
            arrived_ns=arrived_ns,
            passed=reason,
            depth_stamp_ns=None if first is None or first.frame is None else first.frame.stamp_ns,
            compensation=Compensation.NO_ODOMETRY if first is None else first.compensation,
            deskewed=deskewed,
            timings=_total_timings([s.timings for s in paired if s.timings is not None]),
        )
        output = self._remember(
            self._with_sources(output, base_to_output), paired, base_to_output, swept
        )
        return self._limited(output)

    def _limited(self, output: StreamOutput[T]) -> StreamOutput[T]:
        """`output` within `output_range_min` .. `output_range_max` when they are set
        (`output.within_limits`); published anew then, never as the LiDAR's own bytes."""
        config = self.config
        if not (config.output_range_min > 0.0 or config.output_range_max > 0.0):
            return output
        low, high = config.output_range_min, config.output_range_max
        fused = output.fused if output.fused is not None else output.lidar
        return replace(output, fused=within_limits(fused, low, high))

    # ------------------------------------------------------------ cameras

    def _camera_contribution(
        self,
        feed: CameraFeed,
        output: Scan,
        base_to_output: Transform,
        arrived_ns: int,
        lidar_frame: str | None,
        frame: DepthFrame | None = None,
    ) -> _Seen:
        """One camera's scan on `output`'s grid at its stamp: its frame nearest the stamp
        within its own max_time_offset (`frame`: the one the output was made for, at its
        stamp), placed by its mounting (`_camera_mount`), moved to the stamp through
        odometry, converted with its own settings on its own floor; or why not (counted per
        named camera in `sources.counts` as another source's is)."""
        seen = self._camera_seen(feed, output, base_to_output, arrived_ns, lidar_frame, frame)
        counts = self.sources.counts
        if feed.name not in self.sources.names:
            pass  # the one-source parameters' camera: `counts.passed` says it all
        elif seen.reason is None:
            counts.note(counts.used, feed.name)
        elif seen.reason in (Passed.NO_CAMERA_INFO, Passed.CAMERA_SILENT, Passed.NO_FRAME_NEAR):
            counts.note(counts.missing, feed.name)
        else:
            counts.note(counts.no_mounting, feed.name)
        return seen

    def _camera_seen(
        self,
        feed: CameraFeed,
        output: Scan,
        base_to_output: Transform,
        arrived_ns: int,
        lidar_frame: str | None,
        frame: DepthFrame | None,
    ) -> _Seen:
        if frame is None:
            if feed.model is None:
                return _Seen(feed, Passed.NO_CAMERA_INFO)
            frame = feed.nearest(output.stamp_ns)
            if frame is None:
                silent = (
                    feed.last_arrival_ns is None
                    or arrived_ns - feed.last_arrival_ns > self._camera_timeout_ns
                )
                return _Seen(feed, Passed.CAMERA_SILENT if silent else Passed.NO_FRAME_NEAR)
            motion, compensation = self._motion(frame.stamp_ns, output.stamp_ns, base_to_output)
        else:
            motion, compensation = IDENTITY_MOTION, Compensation.OFF
        mount = self._camera_mount(feed, frame, lidar_frame)
        if mount is None:
            return _Seen(feed, Passed.NO_EXTRINSICS, frame)
        if motion is None:
            return _Seen(feed, Passed.NO_MOTION, frame)
        # The camera's points are binned from the output's origin (the LiDAR's, or
        # `output_frame`'s when the LiDAR was re-binned into it).
        paired = Extrinsics(base_to_laser=base_to_output, base_to_camera_optical=mount)
        try:
            ground, extrinsics = self._on_ground(feed, frame, paired)
            profile = None if feed.ground is None else feed.ground.profile
            result = feed.pipeline.fuse(
                output, frame.depth, frame.camera, paired, motion, ground, profile
            )
        except ScanfuseError as err:
            self.note_malformed('fusion', err)
            return _Seen(feed, Passed.FUSION_FAILED, frame)
        depth_scan = result.depth_scan
        if result.slab_slots is not None:
            depth_scan = self._far_confirmed(feed, frame, depth_scan, result.slab_slots, paired)
        return _Seen(
            feed, None, frame, depth_scan, extrinsics, compensation, result.timings,
            result.slab_slots, mount,
        )  # fmt: skip

    def _far_confirmed(
        self,
        feed: CameraFeed,
        frame: DepthFrame,
        scan: Scan,
        slab_slots: Mask,
        extrinsics: Extrinsics,
    ) -> Scan:
        """`scan` (the camera's readings of `frame`, at the output's stamp) without its slab
        readings beyond `far_confirm_range` that the camera's previous frame did not show
        (`far_confirm`). Without odometry at the stamp, `scan` as it is."""
        far = feed.config.far_confirm_range
        at = self.odometry.pose_at(scan.stamp_ns) if far > 0.0 else None
        if at is None or at.pose is None:
            return scan
        slots = far_readings(scan, slab_slots, far)
        placement = Placement.of(at.pose, extrinsics.base_to_laser)
        points = places(scan, slots, placement)
        if frame.stamp_ns != feed.far_frame:
            # Places across an odometry jump (a reset) lie in another frame: none confirms.
            same_frame = feed.far_segment == at.segment
            feed.far_before = feed.far_now if same_frame else np.zeros((0, 2))
            feed.far_frame = frame.stamp_ns
        feed.far_now, feed.far_segment = points, at.segment
        ranges = scan.ranges[slots].astype(np.float64)
        kept = confirmed(
            points, ranges, feed.far_before, feed.config.depth_noise, (placement.x, placement.y)
        )
        if kept.all():
            return scan
        filtered = scan.ranges.copy()
        filtered[np.flatnonzero(slots)[~kept]] = np.nan
        return scan.with_ranges(filtered)

    def _camera_mount(
        self, feed: CameraFeed, frame: DepthFrame, lidar_frame: str | None
    ) -> Transform | None:
        """Where the camera's optical frame lies on the base; None: refused (said once).
        With a LiDAR, TF when it relates the base to both, the parameters when TF knows
        neither (`extrinsics_for`); without, TF when it knows the camera's frame, else the
        parameters (`mounting`)."""
        if lidar_frame is None:
            mount = self.mounting(frame.optical_frame, feed.base_to_optical)
            if mount is None:
                self._warn_once(
                    f'extrinsics {feed.name}',
                    f'TF does not relate base_frame {self.config.base_frame} to the camera '
                    f'frame {frame.optical_frame}: publish the transform or set use_tf: false',
                )
            return mount
        choice = self.extrinsics_for(lidar_frame, frame.optical_frame, feed.name)
        if choice.extrinsics is None:
            self._warn_once('extrinsics', choice.source)
            return None
        return choice.extrinsics.base_to_camera_optical

    # ------------------------------------------------------------ no LiDAR

    def _camera_triggered(
        self, feed: CameraFeed, frame: DepthFrame, now_ns: int, token: T
    ) -> list[StreamOutput[T]]:
        """A camera-only robot's output for `frame` of `feed` (the trigger), at its stamp;
        none (counted as a fusion failure, said once) when the camera cannot be placed or
        the frame converted."""
        try:
            output = self._camera_output(feed, frame, now_ns, token)
        except (ScanfuseError, ArithmeticError, ValueError) as err:  # as `_settle`
            self.note_malformed('fusion', err)
            self.counts.passed[Passed.FUSION_FAILED] = (
                self.counts.passed.get(Passed.FUSION_FAILED, 0) + 1
            )
            return []
        return [output]

    def _camera_output(
        self, feed: CameraFeed, frame: DepthFrame, now_ns: int, token: T
    ) -> StreamOutput[T]:
        """The output the trigger camera's `frame` makes, every other camera added as to a
        LiDAR's scan.

        The row method with no output grid given is depthimage_to_laserscan: the row scan on
        its own grid (one reading per image column), labelled `output_frame` (else the depth
        image's frame), bit for bit with `d2l_compat`: it is the output as a LiDAR's scan is.
        Otherwise an empty scan on the output grid (`output.default_grid`) from
        `output_frame`'s origin (else base_frame's) takes every camera, this one first."""
        config = self.config
        others = [f for f in self.sources.cameras.values() if f is not feed]
        if config.method is Method.ROW and configured_grid(config) is None:
            mount = self._camera_mount(feed, frame, None)
            if mount is None:
                msg = (
                    f'TF does not relate base_frame {config.base_frame} to the camera frame '
                    f'{frame.optical_frame}: publish the transform or set use_tf: false'
                )
                raise TransformError(msg)
            # The row scan's angles turn about the camera's own vertical axis from its
            # optical axis: the camera body frame (x forward) is where it lies.
            base_to_output = mount @ BODY_TO_OPTICAL.inverse()
            row = feed.pipeline.row_depth_scan(frame.depth, frame.camera)
            scan = row.with_ranges(
                row.ranges,
                frame_id=config.output_frame or frame.frame_id or frame.camera.frame_id,
                stamp_ns=frame.stamp_ns,
            )
            empty = empty_scan(scan.grid, scan.frame_id, scan.stamp_ns, 0.0, scan.range_max)
            own = _Seen(feed, None, frame, None, Extrinsics(base_to_output, mount))
            seen = [
                own,
                *(self._camera_contribution(f, scan, base_to_output, now_ns, None) for f in others),
            ]
            return self._assemble(
                token, now_ns, seen, base_to_output, lidar=empty, fused=scan, depth_scan=scan
            )
        frame_id = config.output_frame or config.base_frame
        base_to_output = self.base_to_output(frame_id)
        grid = default_grid(config)
        empty = empty_scan(grid, frame_id, frame.stamp_ns, config.range_min, config.range_max)
        own = self._camera_contribution(feed, empty, base_to_output, now_ns, None, frame)
        if own.reason is not None:
            hint = (
                ': publish the transform from base_frame to its frame, or set use_tf: false'
                if own.reason is Passed.NO_EXTRINSICS
                else ' (the malformed counts say why)'
            )
            msg = f'the camera {feed.name} makes no output, {own.reason.value}{hint}'
            raise TransformError(msg)
        seen = [
            own,
            *(self._camera_contribution(f, empty, base_to_output, now_ns, None) for f in others),
        ]
        return self._assemble(token, now_ns, seen, base_to_output, lidar=empty, fused=empty)

    def _cloud_triggered(self, stamp_ns: int, now_ns: int, token: T) -> list[StreamOutput[T]]:
        """A clouds-only robot's output at the first cloud's stamp: every cloud's slab
        points (`_with_sources`) on the output grid, from `output_frame`'s origin (else
        base_frame's)."""
        config = self.config
        frame_id = config.output_frame or config.base_frame
        range_max = max(cloud.range_max for cloud in config.sources.clouds)
        empty = empty_scan(default_grid(config), frame_id, stamp_ns, 0.0, range_max)
        try:
            base_to_output = self.base_to_output(frame_id)
            output = self._assemble(token, now_ns, [], base_to_output, lidar=empty, fused=empty)
        except (ScanfuseError, ArithmeticError, ValueError) as err:  # as `_settle`
            self.note_malformed('fusion', err)
            return []
        self.counts.fused += 1
        return [output]

    def _on_ground(
        self, feed: CameraFeed, frame: DepthFrame, extrinsics: Extrinsics
    ) -> tuple[GroundPlane | None, Extrinsics]:
        """The floor of `frame` and the mounting moved onto it (for the memory's slab): the
        mounting tilted by the IMU's pitch and roll at the frame's stamp (`imu`), then found
        in the frame (the camera's `GroundTracker`, once per frame); None and the mounting
        when neither is on."""
        if self.config.method is not Method.OBSTACLE:
            return None, extrinsics
        tilt = self.imu.tilt_at(frame.stamp_ns)
        if tilt is None and len(self.imu):
            self.counts.imu_missed += 1
            self._warn_once(
                'imu', f'no IMU sample within 50 ms of a depth frame on {self.config.imu_topic}: '
                'the mounting is used untilted until it comes back',
            )  # fmt: skip
        mounting = extrinsics.base_to_camera_optical
        prior = GroundPlane.of_mounting(mounting if tilt is None else tilt @ mounting)
        ground = feed.ground
        if ground is None:
            if tilt is None:
                return None, extrinsics
            plane = prior
        else:
            if frame.stamp_ns != feed.ground_frame_ns or ground.estimate is None:
                base = None if tilt is None else GroundPlane.of_mounting(mounting)
                ground.update(frame.depth, frame.camera, prior, base)
                feed.ground_frame_ns = frame.stamp_ns
            plane = ground.estimate or prior
        on_ground = replace(
            extrinsics, base_to_camera_optical=plane.mounting(extrinsics.base_to_camera_optical)
        )
        return plane, on_ground

    def _to_output(self, lidar: Scan) -> tuple[Scan, Transform]:
        """The first LiDAR's scan in the output frame, on the output grid (`_layout`), and
        where that frame lies on the base: its readings re-binned from their points
        (`output.rebinned_lidar`) when the frame or grid is not its own."""
        layout = self._layout(lidar)
        if layout.own is not None:
            return layout.own, layout.base_to_output
        base_to_laser = self.base_to_laser(lidar.frame_id)
        scan = rebinned_lidar(lidar, base_to_laser, layout.base_to_output, layout.grid,
                              layout.frame)  # fmt: skip
        return scan, layout.base_to_output

    def _layout(self, lidar: Scan) -> OutputLayout:
        """The output `lidar` (the first LiDAR's scan) makes: its own frame and grid
        (`full_circle`: a 360-degree grid of its increment, `scan.full_circle`) unless
        `output_frame` or `angle_increment` say otherwise. TransformError when nothing
        places `output_frame` (`base_to_output`)."""
        config = self.config
        grid = configured_grid(config)
        frame = config.output_frame or lidar.frame_id
        wide = full_circle(lidar) if config.full_circle else None
        if frame_name(frame) == frame_name(lidar.frame_id) and grid is None:
            own = lidar if wide is None else wide
            return OutputLayout(own.grid, frame, self.base_to_laser(lidar.frame_id), own)
        base_to_output = self.base_to_output(frame, lidar.frame_id)
        return OutputLayout(grid or (lidar if wide is None else wide).grid, frame, base_to_output)

    def prepare(self, lidar: Scan) -> None:
        """Build every camera's obstacle tables for the output `lidar` makes (its frame and
        grid, `_layout`) now, not on the first fused scan (the node calls it when CameraInfo
        or a new LiDAR grid arrives). Whatever fails is left for that scan to report."""
        if self.config.method is not Method.OBSTACLE:
            return
        for feed in self.sources.cameras.values():
            camera = feed.model
            if camera is None:
                continue
            try:
                layout = self._layout(lidar)
                choice = self.extrinsics_for(layout.frame, camera.frame_id, feed.name)
                if choice.extrinsics is None:
                    continue
                paired = replace(choice.extrinsics, base_to_laser=layout.base_to_output)
                feed.pipeline.prepare(camera, paired, layout.grid)
            except ScanfuseError:
                continue

    def base_to_output(self, frame: str, lidar_frame: str = '') -> Transform:
        """Where the output frame `frame` lies on the base: the base itself, TF, or the
        first LiDAR's mounting when it is that LiDAR's frame (`lidar_frame`). TransformError
        when none of them places it."""
        name, base = frame_name(frame), frame_name(self.config.base_frame)
        if name == base:
            return Transform()
        if self.config.use_tf and self.tf.can_transform(base, name):
            return Transform.from_matrix(self.tf.lookup(base, name))
        if lidar_frame and name == frame_name(lidar_frame):
            return self._parameters.base_to_laser
        msg = (
            f'output_frame {frame!r} is neither base_frame {base!r} nor a frame TF relates to '
            f'it (TF roots: {", ".join(self.tf.roots()) or "none"}): publish its transform or '
            'set output_frame to base_frame'
        )
        raise TransformError(msg)

    # ------------------------------------------------------------ other sources

    def _with_sources(self, output: StreamOutput[T], base_to_output: Transform) -> StreamOutput[T]:
        """`output` with what the other LiDARs and the clouds add (`scanfuse.feeds`);
        `base_to_output`: where the output frame lies on the base."""
        base = output.fused if output.fused is not None else output.lidar
        lidars, clouds = self.sources.point_contributions(base, base_to_output, self)
        # A contribution with no reading at all changes nothing: keep the LiDAR's own bytes.
        lidars = [scan for scan in lidars if not np.isnan(scan.ranges).all()]
        clouds = [scan for scan in clouds if not np.isnan(scan.ranges).all()]
        if not (lidars or clouds):
            return output
        fused = base
        for scan in (*lidars, *clouds):
            fused = merge_scans(fused, scan)
        depth_scan = output.depth_scan
        for scan in clouds:
            depth_scan = scan if depth_scan is None else merge_scans(depth_scan, scan)
        every_lidar = output.lidar
        for scan in lidars:
            every_lidar = merge_scans(every_lidar, scan)
        return replace(output, fused=fused, depth_scan=depth_scan, lidars=every_lidar)

    def mounting(self, frame: str, fallback: Transform) -> Transform | None:
        """A sensor frame's pose in the base frame: from TF when TF knows the frame (None
        when TF cannot relate it to the base), else `fallback` (the source's parameters)."""
        name = frame_name(frame)
        if not self.config.use_tf or name not in set(self.tf.frames):
            return fallback
        base = frame_name(self.config.base_frame)
        try:
            return Transform.from_matrix(self.tf.lookup(base, name))
        except ScanfuseError:
            return None

    def motion_to(
        self, source_ns: int, target_ns: int, base_to_sensor: Transform
    ) -> PlanarMotion | None:
        """Points of a sensor at `source_ns` to that sensor at `target_ns` (None: unknown)."""
        motion, _ = self._motion(source_ns, target_ns, base_to_sensor)
        return motion

    def deskewed(self, scan: Scan) -> Scan:
        """`scan` de-skewed, without the readings on the ground driven over (`trail`)."""
        return self._off_the_trail(self._deskew(scan)[0], advance=False)

    def _beam_tilts(self, scan: Scan, bearings: F64 | None = None) -> F64 | None:
        """The base's tilt when each beam of `scan` (a LiDAR's, on its own grid) was measured
        (N x 3 x 3, `ImuHistory.tilts_over`), or with `bearings` (N, radians in its frame)
        when the beam along each was; None without an IMU across the sweep or the sweep's
        timing (then the tilt at the scan's stamp stands for every beam)."""
        if not len(self.imu):
            return None
        stamps = beam_stamps(scan, bearings)
        return None if stamps is None else self.imu.tilts_over(stamps)

    def _off_the_trail(self, scan: Scan, *, advance: bool) -> Scan:
        """`scan` (a LiDAR's, de-skewed) with its readings on the ground the robot drove
        over dropped (NaN; `scanfuse.trail`); `advance`: the first LiDAR's scan, which moves
        the trail on to its stamp. Unchanged without a trail, an IMU sample or a pose."""
        trail = self.trail
        if trail is None:
            return scan
        tilt = self.imu.tilt_at(scan.stamp_ns)
        at = self.odometry.pose_at(scan.stamp_ns)
        if tilt is None or at.pose is None:
            return scan
        rotation = tilt.rotation_matrix
        if advance:
            trail.advance(at.pose, rotation, at.segment)
        valid = lidar_readings(scan)
        if not valid.any():
            return scan
        points = self.base_to_laser(scan.frame_id).apply(lidar_points(scan, valid))
        beams = self._beam_tilts(scan)
        on_ground = trail.on_ground(
            points, at.pose, rotation, None if beams is None else beams[valid]
        )
        if not on_ground.any():
            return scan
        self.counts.lidar_on_ground += int(on_ground.sum())
        kept = scan.ranges.copy()
        kept[np.flatnonzero(valid)[on_ground]] = np.nan
        return scan.with_ranges(kept)

    def _off_the_seen_ground(
        self, lidar: Scan, seen: list[_Seen], base_to_output: Transform, swept: Scan | None
    ) -> Scan:
        """`lidar` (in the output frame, at `base_to_output` on the base) without the readings
        that lie on the ground a paired camera sees in its frame, below its slab (NaN;
        `scanfuse.seen_ground`): a tilted LiDAR's plane meeting the floor. The frame is taken
        at the scan's stamp: within max_time_offset the robot moves a few centimetres, and the
        floor's height changes by a fraction of that. Its tilt is not taken as the same: with
        an IMU, each reading is turned from the base's tilt when its beam was measured (in
        `swept`, the LiDAR's own scan; None: at the scan's stamp) to the tilt at the frame's
        stamp. A sprung body pitching 20-50 degrees a second, a frame 30 ms off a beam
        puts a reading 2 m out 2-5 cm off the floor the camera saw."""
        if self.config.method is not Method.OBSTACLE:
            return lidar
        valid = lidar_readings(lidar)
        if not valid.any():
            return lidar
        in_base = base_to_output.apply(lidar_points(lidar, valid))
        beams = None
        if swept is not None:
            local = self.base_to_laser(swept.frame_id).inverse().apply(in_base)
            beams = self._beam_tilts(swept, np.arctan2(local[:, 1], local[:, 0]))
        level = None if beams is None else np.einsum('nij,nj->ni', beams, in_base)
        on_ground = np.zeros(int(valid.sum()), dtype=np.bool_)
        for camera in seen:
            frame, extrinsics, mount = camera.frame, camera.extrinsics, camera.mount
            if camera.reason is not None or frame is None or extrinsics is None or mount is None:
                continue
            own = camera.feed.config
            points = in_base
            tilt = None if level is None else self.imu.tilt_at(frame.stamp_ns)
            if level is not None and tilt is not None:
                points = level @ tilt.rotation_matrix  # on the base as tilted at the frame
            on_ground |= on_seen_ground(
                mount.inverse().apply(points),
                frame.depth,
                frame.camera,
                GroundPlane.of_mounting(extrinsics.base_to_camera_optical),
                None if camera.feed.ground is None else camera.feed.ground.profile,
                below=own.min_obstacle_height,
                range_min=own.range_min,
                range_max=own.range_max,
            )
        if not on_ground.any():
            return lidar
        self.counts.lidar_on_seen_ground += int(on_ground.sum())
        kept = lidar.ranges.copy()
        kept[np.flatnonzero(valid)[on_ground]] = np.nan
        return lidar.with_ranges(kept)

    # ------------------------------------------------------------ memory

    def _remember(
        self,
        output: StreamOutput[T],
        paired: list[_Seen],
        base_to_output: Transform,
        swept: Scan | None = None,
    ) -> StreamOutput[T]:
        """Clear, add, forget, and merge the remembered obstacles into `output` (in the
        output frame, which lies at `base_to_output` on the base); `paired`: the cameras
        whose frames it took; `swept`: the LiDAR's scan as measured (`_corrected`)."""
        memory = self.memory
        if memory is None or not len(self.odometry):
            return output
        scan = output.lidar
        base = self.odometry.pose_at(scan.stamp_ns)
        if base.pose is None:
            self._memory_frozen(scan.stamp_ns)
            return output
        if self._memory_segment is not None and base.segment != self._memory_segment:
            self._drop_memory('odometry jumped (reset or relocalisation)')  # and the drift
        self._memory_segment = base.segment
        self._memory_placed_ns = scan.stamp_ns
        self._age_while_moving(memory, scan.stamp_ns, base.pose)
        pose = self._corrected(scan, base.pose, base_to_output, swept)
        placement = Placement.of(pose, base_to_output)
        robot = (pose.x, pose.y)
        # Every camera forgets what it sees free (a rear camera behind a reversing robot)
        # and remembers its slab, each frame once, with its own slab and floor.
        for camera in paired:
            feed, frame, extrinsics = camera.feed, camera.frame, camera.extrinsics
            if frame is None or extrinsics is None or frame.stamp_ns == feed.cleared_with:
                continue
            profile = None if feed.ground is None else feed.ground.profile
            seen_from = self._clear_seen(
                memory, frame.stamp_ns, frame.depth, frame.camera,
                extrinsics.base_to_camera_optical, feed.slab, profile,
            )  # fmt: skip
            if seen_from is None:
                continue
            feed.cleared_with = frame.stamp_ns
            if output.depth_scan is not None:
                self._slab_points[feed.name] = (frame.stamp_ns, *self._add_slab(
                    memory, feed, frame, seen_from, output.depth_scan, output.every_lidar,
                    placement, robot,
                ))  # fmt: skip
        if output.depth_scan is not None:
            unseen = lidar_misses(output.depth_scan, output.every_lidar, LIDAR_SEES_MARGIN)
            keep = unseen.copy()
            for camera in paired:
                taken = _slab_readings(camera, output.depth_scan)
                keep &= ~taken
                self._add_pixels_for(memory, camera, output.depth_scan, taken & unseen,
                                     placement, scan.stamp_ns, robot)  # fmt: skip
            memory.add_scan(output.depth_scan, placement, scan.stamp_ns, keep, robot=robot)
        # Readings are added from the level placement: a camera's reading lies in the
        # tilted body's plane, and setting it down level turns it about the base's origin,
        # which is exact at the ground's height, where low obstacles stand. They are drawn
        # from where the LiDAR stands on the tilted body (the IMU's), as its own readings
        # are: drawn level, a box beside a robot pitched up a 1:8 ramp lay 3.7 cm off.
        drawn_from = Placement.of(pose, base_to_output, self.imu.tilt_at(scan.stamp_ns))
        ranges = memory.scan(drawn_from, scan.grid, robot=robot, now_ns=scan.stamp_ns)
        # REP-117: a published finite reading lies inside its limits. A remembered point
        # nearer than range_min (the robot pushed into it) is no reading of this scan, as
        # the merge already treats it.
        with np.errstate(invalid='ignore'):
            ranges[(ranges < scan.range_min) | (ranges > scan.range_max)] = np.nan
        remembered = scan.with_ranges(
            ranges.astype(np.float32),
            range_min=scan.range_min,
            range_max=scan.range_max,
        )
        instant = output.fused
        if not np.isfinite(remembered.ranges).any():
            return replace(output, instant=instant, memory_scan=remembered)
        self.counts.remembered += 1
        fused = merge_scans(instant if instant is not None else output.lidar, remembered)
        return replace(output, fused=fused, instant=instant, memory_scan=remembered)

    def _corrected(
        self, scan: Scan, base: PlanarPose, base_to_laser: Transform, swept: Scan | None = None
    ) -> PlanarPose:
        """The base's pose in the memory's frame at `scan`'s stamp, the drift correction
        first updated from `scan` (the first LiDAR's, de-skewed when odometry allowed; at
        `base_to_laser` on the base). A scan levelled for matching is levelled beam by beam
        with the tilt of each beam's time in `swept` (the scan as measured; None: the tilt
        at the stamp for all). Without a LiDAR there are no walls to match: odometry alone."""
        if not (self.config.memory_scan_matching and self.config.has_lidar):
            return base
        tilt = self.imu.tilt_at(scan.stamp_ns)  # None: no IMU sample then, taken as level
        beams = None
        if tilt is not None and swept is not None:
            angles = scan.angles()
            directions = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(angles.size)])
            to_swept = self.base_to_laser(swept.frame_id).inverse() @ base_to_laser
            local = directions @ to_swept.rotation_matrix.T
            beams = self._beam_tilts(swept, np.arctan2(local[:, 1], local[:, 0]))
        before, anchored = self.drift.correction, self.drift.anchored
        result = self.drift.update(
            scan,
            base,
            base_to_laser,
            tilt=0.0 if tilt is None else plane_tilt(tilt, base_to_laser),
            base_tilt=beams if beams is not None or tilt is None else tilt.rotation_matrix,
        )
        memory, anchor_ns = self.memory, self.drift.anchored_since_ns
        if memory is not None:
            if self.drift.anchored > anchored and anchor_ns is not None:
                # Re-anchored after a tilted stretch (a ramp): what the memory took since
                # the anchor was placed on the frame before, with the slip now taken out.
                change = self.drift.correction.compose(before.inverse())
                self._move_remembered(memory, anchor_ns, change)
            self._memory_path.append((scan.stamp_ns, memory.clock(scan.stamp_ns), base))
        if result is not None and result.refused is not None:
            self.counts.drift_refused += 1
            self._note_once(
                f'drift {result.refused.name}',
                f'memory scan matching refused ({result.refused.value}): the memory follows '
                'odometry alone from that scan on, until a match succeeds again',
            )
        elif result is not None:
            self.counts.drift_matched += 1
        return self.drift.corrected(base)

    def _move_remembered(self, memory: ObstacleMemory, anchor_ns: int, change: PlanarPose) -> None:
        """Move what `memory` took after the scan at `anchor_ns`, on the frame the drift
        correction has just moved by `change`, by the share of `change` the wheels had
        slipped by then: the share of the path from the anchor they had driven (slip grows
        with the distance driven; what was taken after the last scan of the path, all of
        it). Nothing moves when the anchor's scan has left the path."""
        path = list(self._memory_path)
        start = next((k for k, (stamp, _, _) in enumerate(path) if stamp == anchor_ns), None)
        if start is None:
            return
        steps = path[start:]
        lengths = np.cumsum(
            [math.hypot(b.x - a.x, b.y - a.y) for (_, _, a), (_, _, b) in pairwise(steps)]
        )
        total = float(lengths[-1]) if lengths.size else 0.0
        since = steps[0][1]
        for (_, clock, _), length in zip(steps[1:], lengths, strict=True):
            share = float(length) / total if total > 0.0 else 1.0
            part = PlanarPose(change.x * share, change.y * share, change.yaw * share)
            memory.move_since(since, part, until=clock)
            since = clock
        memory.move_since(since, change)

    def _clear_seen(
        self,
        memory: ObstacleMemory,
        stamp_ns: int,
        depth: npt.NDArray[np.generic],
        camera: CameraModel,
        base_to_optical: Transform,
        slab: tuple[float, float],
        profile: GroundProfile | None = None,
    ) -> Transform | None:
        """Forget what one depth frame sees free (above the ramps of `profile`, its ground);
        the camera's optical frame in odom (None: odometry cannot place the frame yet)."""
        camera_base = self.odometry.pose_at(stamp_ns)
        if camera_base.pose is None or camera_base.segment != self._memory_segment:
            return None
        base = camera_base.pose
        if self.config.memory_scan_matching:
            base = self.drift.corrected(base)  # the memory's frame (see `_corrected`)
        odom_to_base = Transform.from_rpy(0.0, 0.0, base.yaw, (base.x, base.y, 0.0))
        odom_to_optical = odom_to_base @ base_to_optical
        config = self.config
        self.counts.memory_cleared += memory.clear_seen(
            depth,
            camera,
            odom_to_optical,
            slab=slab,
            range_min=config.range_min,
            range_max=config.range_max,
            profile=profile,
        )
        return odom_to_optical

    def _add_slab(
        self,
        memory: ObstacleMemory,
        feed: CameraFeed,
        frame: DepthFrame,
        odom_to_optical: Transform,
        depth_scan: Scan,
        lidar: Scan,
        placement: Placement,
        robot: tuple[float, float],
    ) -> tuple[F64, F64]:
        """Remember the slab pixels of `frame` behind their slot's obstacle reading that
        agree with their neighbours, as the mean of each dense cell's: a box's sides and far
        corners, not only the face nearest the LiDAR, so that what clearing forgets of a
        place is replaced by all the camera sees there. Returns those pixels (odometry
        frame)."""
        config = self.config
        own = feed.config
        profile = None if feed.ground is None else feed.ground.profile
        x, y = slab_points(
            frame.depth,
            frame.camera,
            odom_to_optical,
            slab=(own.min_obstacle_height, own.max_obstacle_height),
            range_min=config.range_min,
            range_max=config.range_max,
            agreement=MEMORY_NEIGHBOUR_AGREEMENT,
            bottom_noise=own.slab_noise_sigmas * own.depth_noise,
            # The ramps of this frame's ground, as its obstacle scan measured (the same lifts).
            lifts=None
            if profile is None
            else profile.slab_lifts(
                frame.camera, own.range_max, own.min_obstacle_height, own.max_obstacle_height
            ),
        )
        keep = worth_remembering(x, y, depth_scan, lidar, placement, LIDAR_SEES_MARGIN)
        x, y = x[keep], y[keep]
        memory.add_dense(x, y, depth_scan.stamp_ns, min_count=MEMORY_CELL_PIXELS, robot=robot)
        return x, y

    def _add_pixels_for(
        self,
        memory: ObstacleMemory,
        camera: _Seen,
        depth_scan: Scan,
        slots: Mask,
        placement: Placement,
        stamp_ns: int,
        robot: tuple[float, float],
    ) -> None:
        """Remember, for each of `camera`'s slab readings in `slots` (the merged
        `depth_scan`'s, seen from `placement`), the pixel its frame gave the memory in that
        slot nearest the reading's range (`READING_PIXEL_WITHIN`): where the obstacle is,
        not on the slot's centre line. A reading no such pixel stands for (the floor's noise
        that one slot lifted into the slab) is not remembered."""
        if camera.frame is None or not slots.any():
            return
        given = self._slab_points.get(camera.feed.name)
        if given is None or given[0] != camera.frame.stamp_ns:
            return  # not this frame's pixels: none stands for its readings
        _, x, y = given
        chosen = nearest_pixels(x, y, depth_scan, slots, placement, READING_PIXEL_WITHIN)
        memory.add(x[chosen], y[chosen], stamp_ns, robot=robot)

    def _age_while_moving(self, memory: ObstacleMemory, stamp_ns: int, pose: PlanarPose) -> None:
        """Stop the memory's clock for the time since the last scan if odometry says the
        robot stood still (`memory_ages_while_stopped` false)."""
        last = self._memory_motion
        if last is not None and stamp_ns <= last[0]:
            return  # another LiDAR's older scan: that time is counted already
        self._memory_motion = (stamp_ns, pose)
        if self.config.memory_ages_while_stopped or last is None:
            return
        seconds = (stamp_ns - last[0]) / 1e9
        moved = math.hypot(pose.x - last[1].x, pose.y - last[1].y)
        turned = abs(math.remainder(pose.yaw - last[1].yaw, 2.0 * math.pi))
        if moved <= STILL_SPEED * seconds and turned <= STILL_TURN_RATE * seconds:
            memory.stand_still(stamp_ns - last[0])

    def _memory_frozen(self, stamp_ns: int) -> None:
        placed = self._memory_placed_ns
        timeout = seconds_to_ns(self.config.memory_odometry_timeout)
        if placed is not None and stamp_ns - placed > timeout:
            self._drop_memory(
                f'no usable odometry for {(stamp_ns - placed) / 1e9:.1f} s '
                '(memory_odometry_timeout)'
            )
            self._memory_placed_ns = None

    def _drop_memory(self, why: str) -> None:
        self.drift.reset()  # the odometry frame the correction was for is gone too
        self._slab_points.clear()  # and the pixels placed in it
        if self.memory is not None and len(self.memory):
            self.memory.clear()
            self.counts.memory_dropped += 1
            self._warn_once(f'memory dropped: {why}', f'obstacle memory dropped: {why}')

    # ------------------------------------------------------------ extrinsics

    def extrinsics_for(
        self, scan_frame: str, camera_frame: str, source: str | None = None
    ) -> ExtrinsicsChoice:
        """The extrinsics of this LiDAR frame and the camera `source` names (None: the one
        on `depth_topic`) in `camera_frame`, from TF or the parameters."""
        feed = self.sources.camera(source)
        name = '' if feed is None else feed.name
        key = (frame_name(scan_frame), frame_name(camera_frame), name)
        choice = self._extrinsics.get(key)
        if choice is None:
            choice = self._extrinsics[key] = self._choose_extrinsics(*key)
        self.extrinsics_source = choice.source
        self._extrinsics_key = key
        return choice

    def _choose_extrinsics(self, laser: str, camera: str, name: str) -> ExtrinsicsChoice:
        feed = self.sources.cameras.get(name)
        parameters = self._parameters
        if feed is not None:  # the camera's own mounting parameters
            parameters = replace(parameters, base_to_camera_optical=feed.base_to_optical)
        if not self.config.use_tf:
            return ExtrinsicsChoice(parameters, 'parameters (use_tf is false)')
        known = set(self.tf.frames)
        if laser not in known and camera not in known:
            missing = f'no {laser} or {camera} on /tf_static or /tf yet'
            return ExtrinsicsChoice(
                parameters, f'parameters (TF has neither sensor frame: {missing})'
            )
        base = frame_name(self.config.base_frame)
        try:
            extrinsics = Extrinsics(
                base_to_laser=Transform.from_matrix(self.tf.lookup(base, laser)),
                base_to_camera_optical=Transform.from_matrix(self.tf.lookup(base, camera)),
            )
        except (TransformError, ScanfuseError) as err:
            return ExtrinsicsChoice(None, self._refusal(base, laser, camera, err))
        frames = frozenset(self.tf.chain(base, laser) | self.tf.chain(base, camera))
        return ExtrinsicsChoice(extrinsics, f'TF ({base} -> {laser}, {camera})', frames)

    def _refusal(self, base: str, laser: str, camera: str, err: Exception) -> str:
        roots = self.tf.roots()
        sensor_roots = sorted(
            {self.tf.root_of(f) for f in (laser, camera) if f in set(self.tf.frames)}
        )
        suggestion = next((r for r in sensor_roots if r != base), None)
        hint = f'; base_frame {suggestion!r}?' if suggestion else ''
        return (
            f'TF does not connect base_frame {base!r} to the LiDAR frame {laser!r} and the camera '
            f'frame {camera!r} (TF roots: {", ".join(roots) or "none"}{hint}): set base_frame to '
            f'the robot frame whose z = 0 is the floor, publish the missing transforms, or set '
            f'use_tf: false to use the mounting parameters ({err})'
        )

    def base_to_laser(self, scan_frame: str) -> Transform:
        """The LiDAR's mounting: TF when it knows it, else the parameters."""
        base, laser = frame_name(self.config.base_frame), frame_name(scan_frame)
        if self.config.use_tf and self.tf.can_transform(base, laser):
            return Transform.from_matrix(self.tf.lookup(base, laser))
        return self._parameters.base_to_laser

    # ------------------------------------------------------------ motion

    def _motion(
        self, depth_ns: int, scan_ns: int, base_to_laser: Transform
    ) -> tuple[PlanarMotion | None, Compensation]:
        if not self.config.motion_compensation:
            return IDENTITY_MOTION, Compensation.OFF
        if not len(self.odometry):
            self._note_once(
                'no odometry',
                f'no odometry (on {self.config.odom_topic} or TF {self.config.odom_frame} -> '
                f'{self.config.base_frame}): fusing without motion compensation',
            )
            return IDENTITY_MOTION, Compensation.NO_ODOMETRY
        move, how = self.odometry.move_between(depth_ns, scan_ns)
        if move is None:
            self._warn_once(
                f'motion {how.value}',
                f'depth frame at {depth_ns / 1e9:.3f} s and scan at {scan_ns / 1e9:.3f} s: '
                f'{how.value}; the LiDAR passes through (further ones are only counted)',
            )
            return None, Compensation.NO_ODOMETRY
        return PlanarMotion.of_base_move(move, base_to_laser), Compensation.COMPENSATED

    def _deskew(self, scan: Scan) -> tuple[Scan, bool]:
        """The scan with every beam at the scan's stamp, when odometry covers the sweep."""
        if (
            not self.config.deskew
            or not self.config.motion_compensation
            or scan.time_increment == 0.0
            or len(scan) < 2
            or not len(self.odometry)
        ):
            return scan, False
        sweep_ns = scan.time_increment * (len(scan) - 1) * NANOSECONDS
        if not math.isfinite(sweep_ns) or abs(sweep_ns) > NANOSECONDS:
            self._warn_once(
                'time_increment',
                f'LiDAR time_increment {scan.time_increment} s makes a sweep of '
                f'{sweep_ns / 1e9:.3f} s: not de-skewing',
            )
            return scan, False
        base_to_laser = self.base_to_laser(scan.frame_id)
        samples = np.linspace(0, len(scan) - 1, DESKEW_SAMPLES)
        angle, tx, ty = [], [], []
        for beam in samples:
            beam_ns = scan.stamp_ns + round(float(beam) * scan.time_increment * NANOSECONDS)
            move, _ = self.odometry.move_between(beam_ns, scan.stamp_ns)
            if move is None:
                return scan, False
            motion = PlanarMotion.of_base_move(move, base_to_laser)
            angle.append(motion.angle)
            tx.append(motion.tx)
            ty.append(motion.ty)
        beams = np.arange(len(scan), dtype=np.float64)
        deskewed = deskew_scan(
            scan,
            np.interp(beams, samples, np.unwrap(angle)),
            np.interp(beams, samples, tx),
            np.interp(beams, samples, ty),
        )
        self.counts.deskewed += 1
        return deskewed, True

    # ------------------------------------------------------------ logging

    def _note_once(self, key: str, message: str) -> None:
        """Said once, at DEBUG: a normal way to run (a robot without odometry), not a fault;
        reports and /diagnostics count it."""
        if key not in self._warned:
            self._warned.add(key)
            logger.debug(message)

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            logger.warning(message)


def beam_stamps(scan: Scan, bearings: F64 | None = None) -> npt.NDArray[np.int64] | None:
    """When each beam of `scan` (a LiDAR's, on its own grid) was measured: beam i at its
    stamp plus i time_increment; with `bearings` (radians, the LiDAR's frame), the beam along
    each. None when the scan gives no sweep (time_increment 0, or a sweep over a second, as
    `_deskew` refuses it)."""
    sweep_ns = scan.time_increment * (len(scan) - 1) * NANOSECONDS
    if scan.time_increment == 0.0 or not math.isfinite(sweep_ns) or abs(sweep_ns) > NANOSECONDS:
        return None
    if bearings is None:
        beams = np.arange(len(scan), dtype=np.float64)
    else:
        # Slots from angle_min the way the scan turns, as `scan_matching.levelled` bins them.
        step, turn = abs(scan.angle_increment), math.copysign(1.0, scan.angle_increment)
        along = np.mod(turn * (bearings - scan.angle_min) + step / 2, TWO_PI) - step / 2
        beams = np.clip(np.round(along / step), 0, len(scan) - 1)
    offsets = np.rint(beams * scan.time_increment * NANOSECONDS).astype(np.int64)
    return scan.stamp_ns + offsets


def _total_timings(timings: list[StageTimings]) -> StageTimings | None:
    """Every camera's stage times added up (None: no camera converted a frame)."""
    if not timings:
        return None
    return StageTimings(
        sum(t.convert for t in timings),
        sum(t.resample for t in timings),
        sum(t.merge for t in timings),
    )


def _without_error_values(scan: Scan) -> Scan:
    """`scan` with every finite value that is no real reading (`normalized_ranges`) as NaN;
    `scan` itself when it holds none, so that its own bytes can be published."""
    ranges = normalized_ranges(scan)
    if np.array_equal(ranges, scan.ranges, equal_nan=True):
        return scan
    return scan.with_ranges(ranges)


def _planar(transform: StampedTransform) -> PlanarPose:
    x, y, z, w = transform.rotation
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return PlanarPose(transform.translation[0], transform.translation[1], yaw)
