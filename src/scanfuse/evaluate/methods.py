"""The methods the evaluation compares, each a `FusionConfig` variant of the one pipeline.

- `lidar`: the LiDAR alone, no fusion (the baseline the paper starts from);
- `row-centre`: the paper's default, the principal-point row (Algorithm 1);
- `row-low`: a row below the centre with the paper's range trade-off, the
  floor cut per column by floor_guard (section 3.2);
- `d2l`: depthimage_to_laserscan's band of rows around the centre;
- `obstacle`: the height-filtered full-frame obstacle scan (ours), its depth range
  capped at 3 m: beyond, the stereo noise (sigma = 0.01 Z^2) exceeds the tolerance;
- `obstacle-nearest`, `obstacle-nearest-3m`: the same scan reporting the plain
  nearest point per slot (before the noise-robust statistic), over the camera's full
  range and capped at 3 m.

- `obstacle-no-ground`: `obstacle` with `ground_estimate: false` and no IMU: heights above
  the mounting's plane, as before issue 25 (the floor is not found in each frame, the
  body's tilt not followed). The other fused methods take the simulated IMU.

- `obstacle` is the shipped default, obstacle memory on; `obstacle-no-memory` the
  instantaneous fused scan; `obstacle-uncompensated`: that one with motion_compensation
  false: the depth frame is fused as if taken at the scan's stamp and the LiDAR is not
  de-skewed.

The row methods run with both resamplers (`-linear`, Algorithm 3, and
`-conservative`).

Every fusing method runs in its own `FusionStream`, fed as the node is fed (`MethodStream`):
pairing, pass-through and motion compensation are the stream's. `lidar` is the driver's
scan as it arrives, with no stream (a robot without scanfuse: not de-skewed either).

On a robot with several named sources (the simulator's `amr`: two LiDARs, two cameras),
`lidar` is its LiDARs merged by a `FusionStream` that is given no camera (the 360-degree
scan a laser merger makes, without obstacle memory), and the fusing methods take every
source.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import yaml

from scanfuse.config import FusionConfig, Method, Resampler
from scanfuse.errors import ConfigError
from scanfuse.evaluate.attribution import slot_sources
from scanfuse.motion import PlanarPose
from scanfuse.stream import FusionStream

if TYPE_CHECKING:
    from collections.abc import Iterable

    from scanfuse.camera import CameraModel
    from scanfuse.evaluate.attribution import Sources
    from scanfuse.frames import StampedTransform
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import (
        CloudFrame,
        DepthFrame,
        ImuSample,
        LidarFrame,
        StateSample,
    )
    from scanfuse.stream import StreamCounts, StreamOutput

# Where the low row looks: this share of the way from the centre row to the bottom.
LOW_ROW_SHARE = 0.5
# Rows in the depthimage_to_laserscan band (its `scan_height`).
D2L_BAND = 10
# Depth beyond this is left to the LiDAR by the obstacle method: the simulated D435's
# noise (0.01 Z^2: 9 cm at 3 m) exceeds the 0.05 m + 2 % tolerance beyond it.
OBSTACLE_RANGE_MAX = 3.0
# The row methods (the paper, depthimage_to_laserscan) use the camera's full range.
CAMERA_RANGE_MAX = 10.0


@dataclass(frozen=True)
class MethodSpec:
    """One compared method: a name, a description, and its changes to the base config."""

    name: str
    description: str
    changes: tuple[tuple[str, object], ...] = ()
    fuses: bool = True
    imu: bool = True  # given the simulated IMU (as `scanfuse bag` takes a bag's one Imu topic)

    def config(self, base: FusionConfig, camera: CameraModel) -> FusionConfig:
        """The full configuration of this method for a robot described by `base`."""
        values = dict(self.changes)
        if values.pop('low_row', False):
            centre = round(camera.cy)
            values['scan_row'] = centre + round(LOW_ROW_SHARE * (camera.height - 1 - centre))
        return base.with_changes(**values)


def _row(resampler: Resampler, **extra: object) -> tuple[tuple[str, object], ...]:
    return (
        ('method', Method.ROW),
        ('resample', resampler),
        ('range_max', CAMERA_RANGE_MAX),
        *extra.items(),
    )


METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in (
        MethodSpec('lidar', 'LiDAR alone (no fusion)', fuses=False),
        MethodSpec(
            'row-centre-linear',
            'centre row, linear resampling (the paper as published)',
            _row(Resampler.LINEAR, floor_guard=False),
        ),
        MethodSpec(
            'row-centre',
            'centre row, conservative resampling',
            _row(Resampler.CONSERVATIVE, floor_guard=False),
        ),
        MethodSpec(
            'row-low-linear',
            'low row with floor cut (eq. 4-6), linear resampling',
            _row(Resampler.LINEAR, floor_guard=True, low_row=True),
        ),
        MethodSpec(
            'row-low',
            'low row with floor cut (eq. 4-6), conservative resampling',
            _row(Resampler.CONSERVATIVE, floor_guard=True, low_row=True),
        ),
        MethodSpec(
            'd2l',
            f'depthimage_to_laserscan band of {D2L_BAND} centre rows',
            _row(Resampler.LINEAR, d2l_compat=True, scan_height=D2L_BAND, floor_guard=False),
        ),
        MethodSpec(
            'obstacle',
            'height-filtered full-frame obstacle scan (ours), depth capped at 3 m',
            (('method', Method.OBSTACLE), ('range_max', OBSTACLE_RANGE_MAX)),
        ),
        MethodSpec(
            'obstacle-no-ground',
            "obstacle with ground_estimate false, no IMU: heights above the mounting's plane",
            (
                ('method', Method.OBSTACLE),
                ('range_max', OBSTACLE_RANGE_MAX),
                ('ground_estimate', False),
            ),
            imu=False,
        ),
        MethodSpec(
            'obstacle-no-memory',
            'obstacle without the obstacle memory (the instantaneous fused scan)',
            (('method', Method.OBSTACLE), ('range_max', OBSTACLE_RANGE_MAX), ('memory', False)),
        ),
        MethodSpec(
            'obstacle-uncompensated',
            'obstacle-no-memory without motion compensation (depth frame and LiDAR sweep '
            'taken as at the stamp)',
            (
                ('method', Method.OBSTACLE),
                ('range_max', OBSTACLE_RANGE_MAX),
                ('memory', False),
                ('motion_compensation', False),
            ),
        ),
        MethodSpec(
            'obstacle-nearest',
            'obstacle scan, plain nearest point per slot, full depth range',
            (
                ('method', Method.OBSTACLE),
                ('obstacle_min_points', 1),
                ('range_max', CAMERA_RANGE_MAX),
            ),
        ),
        MethodSpec(
            'obstacle-nearest-3m',
            'obstacle scan, plain nearest point per slot, depth capped at 3 m',
            (
                ('method', Method.OBSTACLE),
                ('obstacle_min_points', 1),
                ('range_max', OBSTACLE_RANGE_MAX),
            ),
        ),
    )
}
# What the closed loop drives with: one of each kind, the row methods conservative.
CLOSED_LOOP_METHODS = (
    'lidar',
    'row-centre',
    'row-low',
    'd2l',
    'obstacle',
    'obstacle-no-memory',
    'obstacle-uncompensated',
)


# A method with some fusion parameters changed: BASE[NAME=VALUE,...], the values as YAML
# reads them (`obstacle[memory_scan_matching=false]`). Scored on the same drives as BASE, it
# measures a change without the closed loop's chance (one stall moves a run's metrics more
# than most changes do).
_VARIANT = re.compile(r'(?P<base>[\w-]+)\[(?P<changes>[^\[\]]*)\]')


def method_spec(name: str) -> MethodSpec:
    """The method called `name`: one of `METHODS`, or a fusing one with changed parameters
    (`BASE[NAME=VALUE,...]`)."""
    spec = METHODS.get(name)
    if spec is not None:
        return spec
    variant = _VARIANT.fullmatch(name)
    base = METHODS.get(variant['base']) if variant else None
    if variant is None or base is None or not base.fuses:
        msg = (
            f'unknown method {name!r}; choose from {", ".join(METHODS)}, or a fusing one with '
            'parameters changed, e.g. obstacle[memory_scan_matching=false,ground_smoothing=0.5]'
        )
        raise ConfigError(msg)
    changes = _parameter_changes(name, variant['changes'])
    FusionConfig().with_changes(**changes)  # an unknown name or a wrong value fails here
    return MethodSpec(
        name,
        f'{base.name} with {variant["changes"]} (scored on the same scans)',
        tuple({**dict(base.changes), **changes}.items()),
        fuses=base.fuses,
        imu=base.imu,
    )


def _parameter_changes(name: str, text: str) -> dict[str, object]:
    """NAME=VALUE pairs, comma-separated, the values as YAML reads them."""
    changes: dict[str, object] = {}
    for pair in text.split(','):
        key, equals, value = (part.strip() for part in pair.partition('='))
        if not (key and equals and value):
            msg = f'method {name!r}: {pair.strip()!r} is not NAME=VALUE (e.g. memory=false)'
            raise ConfigError(msg)
        changes[key] = yaml.safe_load(value)
    return changes


class MethodStream:
    """One method fed the simulator's events as the node is fed its topics.

    Odometry (the wheel odometry, 50 Hz, as nav_msgs/Odometry), CameraInfo and a depth
    image at each image's delivery, and each scan at its delivery: `now_ns` is always the
    simulated delivery time, and the stream releases what the node would publish then.
    `lidar` (no fusion) releases every scan unchanged at once.
    """

    def __init__(
        self,
        name: str,
        base: FusionConfig,
        camera: CameraModel,
        transforms: Iterable[StampedTransform] = (),
    ) -> None:
        self.name = name
        self.spec = method_spec(name)
        self.config = self.spec.config(base, camera)
        self.stream: FusionStream[LidarFrame] | None = None
        # Several LiDARs: even the camera-less method merges them in a stream.
        merges = len(base.sources.lidars) > 1
        self.takes_depth = self.spec.fuses
        # With `record_sources` set, the source of every fused scan's readings
        # (`attribution.slot_sources`), by the scan's stamp, until the scorer takes it.
        self.record_sources = False
        self.sources: dict[int, Sources] = {}
        if self.spec.fuses or merges:
            if not self.spec.fuses:
                self.config = base.with_changes(memory=False)
            # The node's defaults: pair with the frames already received, release at once.
            self.stream = FusionStream(self.config, pair_wait=0.0)
            self.stream.add_transforms(transforms, static=True)

    def add_state(self, sample: StateSample) -> list[tuple[LidarFrame, Scan]]:
        if self.stream is None:
            return []
        odometry = sample.odometry
        self.stream.add_odometry(sample.stamp_ns, PlanarPose(odometry.x, odometry.y, odometry.yaw))
        return self._out(self.stream.tick(sample.stamp_ns))

    def add_imu(self, sample: ImuSample) -> None:
        """The simulated IMU (frame base_link), as `scanfuse bag` takes a recording's one Imu
        topic: the base's tilt at each depth frame."""
        if self.stream is not None and self.spec.imu:
            self.stream.add_imu(sample.stamp_ns, sample.orientation, 'base_link')

    def add_depth(self, frame: DepthFrame, frame_id: str) -> list[tuple[LidarFrame, Scan]]:
        if self.stream is None:
            return []
        if not self.takes_depth:
            return self._out(self.stream.tick(frame.arrival_ns))
        source = frame.source or None  # the camera's name on a robot with several
        self.stream.add_camera_info(frame.camera, source)
        return self._out(
            self.stream.add_depth(
                frame.stamp_ns, frame.depth, frame.arrival_ns, frame_id, source=source
            )
        )

    def add_cloud(self, frame: CloudFrame) -> list[tuple[LidarFrame, Scan]]:
        """A 3D LiDAR's cloud: used by the fusing methods (`lidar` takes the 2D LiDARs only)."""
        if self.stream is None:
            return []
        if not self.takes_depth:
            return self._out(self.stream.tick(frame.arrival_ns))
        return self._out(
            self.stream.add_cloud(
                frame.stamp_ns, frame.points, frame.arrival_ns, frame.frame_id, frame.source
            )
        )

    def add_scan(self, frame: LidarFrame) -> list[tuple[LidarFrame, Scan]]:
        if self.stream is None:
            return [(frame, frame.scan)]
        source = frame.source or None  # the first LiDAR's scans make the output scans
        return self._out(self.stream.add_scan(frame.scan, frame, frame.arrival_ns, source))

    def finish(self) -> list[tuple[LidarFrame, Scan]]:
        return [] if self.stream is None else self._out(self.stream.finish())

    @property
    def counts(self) -> StreamCounts | None:
        return None if self.stream is None else self.stream.counts

    def _out(self, outputs: list[StreamOutput[LidarFrame]]) -> list[tuple[LidarFrame, Scan]]:
        released = []
        for output in outputs:
            # fused None: the stream passed the LiDAR's own scan through unchanged.
            scan = output.token.scan if output.fused is None else output.fused
            if self.record_sources and output.fused is not None:
                self.sources[output.token.stamp_ns] = slot_sources(
                    output.fused, output.depth_scan, output.instant
                )
            released.append((output.token, scan))
        return released
