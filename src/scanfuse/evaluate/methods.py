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

The row methods run with both resamplers (`-linear`, Algorithm 3, and
`-conservative`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from scanfuse.config import FusionConfig, Method, Resampler
from scanfuse.errors import ConfigError
from scanfuse.pipeline import FusionPipeline

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import Scan

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
CLOSED_LOOP_METHODS = ('lidar', 'row-centre', 'row-low', 'd2l', 'obstacle')


def method_spec(name: str) -> MethodSpec:
    spec = METHODS.get(name)
    if spec is None:
        msg = f'unknown method {name!r}; choose from {", ".join(METHODS)}'
        raise ConfigError(msg)
    return spec


class MethodRunner:
    """Turns a LiDAR scan and a depth image into the scan a method gives the robot."""

    def __init__(self, spec: MethodSpec, base: FusionConfig, camera: CameraModel) -> None:
        self.spec = spec
        self.config = spec.config(base, camera)
        self.pipeline = FusionPipeline(self.config) if spec.fuses else None

    def scan(self, lidar: Scan, depth: npt.NDArray[np.generic] | None, camera: CameraModel) -> Scan:
        """The fused scan, or the LiDAR scan for `lidar` or when there is no image yet."""
        if self.pipeline is None or depth is None:
            return lidar
        return self.pipeline.fuse(lidar, depth, camera).fused
