"""`FusionConfig` and loading it from a ROS 2 parameter file.

The same file (`scanfuse: ros__parameters: {...}`) drives the live node, the bag
processor and the simulator. Angles are radians, lengths metres (REP-103).
"""

from __future__ import annotations

import math
from enum import Enum
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from scanfuse.errors import ConfigError

NODE_NAME = 'scanfuse'


class Method(str, Enum):
    """How the depth image becomes a scan."""

    ROW = 'row'  # the paper's Algorithm 1 on one row or a band of rows
    OBSTACLE = 'obstacle'  # every pixel, kept when inside the collision slab


class Resampler(str, Enum):
    """How the row method's scan is brought onto the LiDAR's grid."""

    LINEAR = 'linear'  # the paper's Algorithm 3
    CONSERVATIVE = 'conservative'  # minimum inside each slot, no interpolation across edges


class FusionConfig(BaseModel):
    """Every setting of the fusion. Defaults fit a RealSense D435 above an RPLIDAR."""

    model_config = ConfigDict(frozen=True, extra='forbid', use_enum_values=False)

    method: Method = Field(Method.OBSTACLE, description='depth-to-scan conversion: row | obstacle')
    resample: Resampler = Field(
        Resampler.CONSERVATIVE, description='row method onto the LiDAR grid: linear | conservative'
    )
    scan_row: int | None = Field(
        None, ge=0, description='image row of the row method (default: principal-point row)'
    )
    scan_height: int = Field(1, ge=1, description='rows in the band of the row method')
    d2l_compat: bool = Field(
        default=False, description='row method reproduces depthimage_to_laserscan exactly'
    )
    floor_guard: bool = Field(
        default=True,
        description='row method: cut each slot where its line of sight meets the floor',
    )
    floor_margin: float = Field(
        0.05, ge=0.0, description='metres kept short of the floor intersection by floor_guard'
    )
    range_min: float = Field(0.2, ge=0.0, description='depth camera minimum range, metres')
    range_max: float = Field(
        3.0,
        gt=0.0,
        description=(
            'depth camera maximum range used, metres; active-stereo noise grows with the '
            'square of the range and passes the 0.05 m + 2 % tolerance beyond about 3 m'
        ),
    )
    min_obstacle_height: float = Field(
        0.03, description='bottom of the collision slab above the floor, metres'
    )
    max_obstacle_height: float = Field(
        0.5, description='top of the collision slab above the floor, metres'
    )
    obstacle_min_points: int = Field(
        16,
        ge=1,
        description=(
            'obstacle method: per LiDAR slot, of this many nearest points in the slab the '
            'farthest within obstacle_cluster_spread * range^2 of the nearest is reported. '
            'More than 1 undoes the short bias of the nearest of many noisy depth pixels '
            '(about 2 sigma on a wall); 1 is the plain nearest point. 16 chosen by '
            '`scanfuse evaluate` (false obstacles 8 % -> 0.5 %, recall 0.99 -> 0.97)'
        ),
    )
    obstacle_cluster_spread: float = Field(
        0.02,
        gt=0.0,
        description=(
            "obstacle method: how far behind a slot's nearest point (range r) its other "
            'nearest points count, as this * r^2 metres (1/m; stereo noise grows as r^2: '
            '2 cm at 1 m, 8 cm at 2 m); a thin or low obstacle in front of a wall keeps its '
            'own range. .inf: the plain k-th nearest (+Inf with fewer points). 0.02 chosen '
            'by `scanfuse evaluate` for a RealSense D435 (sigma = 0.01 Z^2)'
        ),
    )
    obstacle_threads: int = Field(
        1,
        ge=1,
        le=64,
        description=(
            'obstacle method: threads per depth frame (image columns split between them, '
            'the scan is the same); 1 runs on the calling thread; 2 only pays with a core to '
            'spare (best frames 1.6-1.9x faster), on busy cores it is slower than 1 because '
            "numba's OpenMP workers wait for a core"
        ),
    )
    camera_x: float = Field(0.0, description='camera position in the base frame, metres')
    camera_y: float = Field(0.0, description='camera position in the base frame, metres')
    camera_height: float = Field(0.45, description='camera height above the floor, metres')
    camera_roll: float = Field(0.0, description='camera roll, radians')
    camera_pitch: float = Field(
        math.radians(20.0), description='camera pitch, radians, positive looks down'
    )
    camera_yaw: float = Field(0.0, description='camera yaw, radians, positive looks left')
    lidar_x: float = Field(0.0, description='LiDAR position in the base frame, metres')
    lidar_y: float = Field(0.0, description='LiDAR position in the base frame, metres')
    lidar_height: float = Field(0.30, description='LiDAR height above the floor, metres')
    lidar_yaw: float = Field(0.0, description='LiDAR yaw in the base frame, radians')
    use_tf: bool = Field(
        default=True, description='take extrinsics from /tf_static and /tf when they are there'
    )
    base_frame: str = Field('base_link', description='robot frame whose z = 0 is the floor')
    max_time_offset: float = Field(
        0.1, gt=0.0, description='largest LiDAR-to-depth stamp difference paired, seconds'
    )
    camera_timeout: float = Field(
        0.5, gt=0.0, description='camera silence after which the LiDAR passes through, seconds'
    )
    publish_depth_scan: bool = Field(
        default=True, description='also publish the depth scan on /scan_depth'
    )
    scan_topic: str = Field('/scan', description='LiDAR LaserScan topic')
    depth_topic: str = Field('/camera/depth/image_raw', description='depth Image topic')
    camera_info_topic: str = Field('/camera/depth/camera_info', description='CameraInfo topic')
    fused_topic: str = Field('/scan_fused', description='fused LaserScan topic')
    depth_scan_topic: str = Field('/scan_depth', description='depth LaserScan topic')

    @model_validator(mode='after')
    def _check_limits(self) -> FusionConfig:
        if self.range_min >= self.range_max:
            msg = f'range_min ({self.range_min}) must be smaller than range_max ({self.range_max})'
            raise ValueError(msg)
        if self.min_obstacle_height >= self.max_obstacle_height:
            msg = (
                f'min_obstacle_height ({self.min_obstacle_height}) must be below '
                f'max_obstacle_height ({self.max_obstacle_height})'
            )
            raise ValueError(msg)
        if self.d2l_compat and self.scan_row is not None:
            msg = (
                'd2l_compat reproduces depthimage_to_laserscan, whose band is always centred '
                'on the principal point: leave scan_row unset or turn d2l_compat off'
            )
            raise ValueError(msg)
        return self

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> FusionConfig:
        """Validate plain values; errors name every bad parameter."""
        try:
            return cls.model_validate(values)
        except ValidationError as err:
            problems = '; '.join(
                f'{".".join(str(p) for p in e["loc"]) or "config"}: {e["msg"]}'
                for e in err.errors()
            )
            msg = f'invalid scanfuse parameters: {problems}'
            raise ConfigError(msg) from err

    @classmethod
    def from_ros_params(cls, path: str | Path, node_name: str = NODE_NAME) -> FusionConfig:
        """Load `<node_name>: ros__parameters: {...}` (or `/**:`) from a ROS 2 parameter file."""
        return cls.from_dict(read_ros_params(path, node_name))

    def to_ros_params(self, node_name: str = NODE_NAME) -> dict[str, Any]:
        """The parameter-file form of this configuration (loadable by ROS 2 and by us)."""
        values = self.model_dump(mode='json', exclude_none=True)
        return {node_name: {'ros__parameters': values}}

    def with_changes(self, **changes: Any) -> FusionConfig:
        """A validated copy with some parameters changed."""
        return self.from_dict({**self.model_dump(), **changes})


def read_ros_params(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """The `ros__parameters` of `node_name` in a ROS 2 parameter file."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as err:
        msg = f'cannot read parameter file {path}: {err.strerror}'
        raise ConfigError(msg) from err
    except yaml.YAMLError as err:
        msg = f'parameter file {path} is not valid YAML: {err}'
        raise ConfigError(msg) from err
    if not isinstance(document, dict):
        msg = f'parameter file {path} must map node names to ros__parameters'
        raise ConfigError(msg)
    candidates = (node_name, f'/{node_name}', '/**')
    for key in candidates:
        section = document.get(key)
        if isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict):
            params: dict[str, Any] = section['ros__parameters']
            return params
    found = ', '.join(str(key) for key in document) or 'nothing'
    msg = (
        f'parameter file {path} has no "{node_name}: ros__parameters:" section '
        f'(found: {found}); see examples/scanfuse.yaml'
    )
    raise ConfigError(msg)
