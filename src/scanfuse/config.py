"""`FusionConfig` and loading it from a ROS 2 parameter file.

The same file (`scanfuse: ros__parameters: {...}`) drives the live node, the bag
processor and the simulator. Angles are radians, lengths metres (REP-103).
"""

from __future__ import annotations

import difflib
import math
from enum import Enum
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from scanfuse.errors import ConfigError
from scanfuse.sources import (
    MAX_MOUNTING_OFFSET,
    SourceSet,
    assemble_fragments_field,
    fragment_timeout_field,
    sources_to_params,
    split_sources,
)

NODE_NAME = 'scanfuse'
# What a parameter file may be (`read_ros_params`): the largest example is 4 KiB.
MAX_PARAMS_BYTES = 1 << 20
MAX_PARAMS_DEPTH = 32
# Parameters of the live node alone (ros.params.NodeSettings), which the one parameter file
# may hold beside the fusion's: the bag processor and the simulator leave them out.
NODE_ONLY = frozenset({'pair_wait', 'lidar_timeout'})

# Physically plausible bounds, checked at every entry (parameter file, `-p`, with_changes).
# A sensor mounted more than 100 m from its robot's base frame is a typo, and a finite float64
# far beyond it (1e39) overflows the float32 arithmetic of the conversions.
MAX_MOUNTING_ANGLE = 2.0 * math.pi  # radians: one full turn either way
MAX_RANGE = 1000.0  # metres, depth camera range limits
MAX_TIME_OFFSET = 10.0  # seconds: 10 s between a scan and an image is no longer one moment
MAX_CAMERA_TIMEOUT = 60.0  # seconds
MAX_OBSTACLE_MIN_POINTS = 64  # per slot and frame the kernel keeps this many nearest points
# Cells of the obstacle memory's rolling grid at most: 2^21 (about 60 MB of arrays). The grid
# has `memory_grid_side` cells a side; MAX_MEMORY_RADIUS fits with the default memory_cell.
MAX_MEMORY_CELLS = 1 << 21
MAX_MEMORY_RADIUS = 18.0  # metres


def memory_grid_side(radius: float, cell: float) -> int:
    """Cells along one side of the memory's rolling grid (covers the radius with a margin)."""
    return math.ceil(2.0 * radius / cell) + 2


def _metres(default: float, description: str, *, bound: float = MAX_MOUNTING_OFFSET) -> Any:
    return Field(default, ge=-bound, le=bound, allow_inf_nan=False, description=description)


def _radians(default: float, description: str) -> Any:
    return Field(
        default,
        ge=-MAX_MOUNTING_ANGLE,
        le=MAX_MOUNTING_ANGLE,
        allow_inf_nan=False,
        description=description,
    )


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
        0.05,
        ge=0.0,
        le=MAX_MOUNTING_OFFSET,
        allow_inf_nan=False,
        description='metres kept short of the floor intersection by floor_guard',
    )
    range_min: float = Field(
        0.2,
        ge=0.0,
        le=MAX_RANGE,
        allow_inf_nan=False,
        description='depth camera minimum range, metres',
    )
    range_max: float = Field(
        3.0,
        gt=0.0,
        le=MAX_RANGE,
        allow_inf_nan=False,
        description=(
            'depth camera maximum range used, metres; active-stereo noise grows with the '
            'square of the range and passes the 0.05 m + 2 % tolerance beyond about 3 m'
        ),
    )
    min_obstacle_height: float = _metres(
        0.03, 'bottom of the collision slab above the floor, metres'
    )
    max_obstacle_height: float = _metres(0.5, 'top of the collision slab above the floor, metres')
    obstacle_min_points: int = Field(
        16,
        ge=1,
        le=MAX_OBSTACLE_MIN_POINTS,
        description=(
            'obstacle method: per LiDAR slot, of this many nearest points in the slab the '
            'farthest within obstacle_cluster_spread * range^2 of the nearest is reported. '
            'More than 1 undoes the short bias of the nearest of many noisy depth pixels '
            '(about 2 sigma on a wall); 1 is the plain nearest point. 16 chosen by '
            '`scanfuse evaluate` (false obstacles 8 % -> 0.5 %, recall 0.99 -> 0.97). At most '
            '64: the kernel keeps k points per slot per frame, and thousands stall it'
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
            'spare (frames back to back 1.5-1.8x faster), on busy cores it is slower than 1 '
            "because numba's OpenMP workers wait for a core, and where a worker idle between "
            'frames is slow to wake (a virtual machine: make bench times frames at 30 Hz) too'
        ),
    )
    detect_drops: bool = Field(
        default=True,
        description=(
            'obstacle method: stairs going down, ledges and holes in the floor are obstacles '
            'at the range where the line of sight crosses the floor; missing returns (0, NaN) '
            'are never drops'
        ),
    )
    drop_min_depth: float = Field(
        0.05,
        gt=0.0,
        le=MAX_MOUNTING_OFFSET,
        allow_inf_nan=False,
        description=(
            'obstacle method: metres below the floor plane a depth point must lie to be a '
            'drop-off (keep it above the error of the floor plane from the mounting)'
        ),
    )
    drop_min_width: float = Field(
        0.0,
        ge=0.0,
        le=MAX_MOUNTING_OFFSET,
        allow_inf_nan=False,
        description=(
            'obstacle method: metres the line of sight must run below the floor beyond its '
            'edge for a drop-off; holes and gaps shorter than this along it (a gap the wheels '
            'roll over) are ignored; 0: every drop counts'
        ),
    )
    depth_noise: float = Field(
        0.01,
        ge=0.0,
        le=1.0,
        allow_inf_nan=False,
        description=(
            'depth camera noise: sigma = depth_noise * Z^2 metres (1/m; RealSense D435 about '
            '0.01); a drop-off needs a reading 6 sigma behind the floor'
        ),
    )
    slab_noise_sigmas: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        allow_inf_nan=False,
        description=(
            "obstacle method: the collision slab's bottom stands this many sigmas of each "
            "depth pixel's height noise (depth_noise Z^2 along its line of sight) above "
            'min_obstacle_height: for a D435 0.4 m up, a sigma is 0.4 cm at 1 m, 1.2 cm at '
            '3 m, so floor that noise lifts into the slab far out stays floor, and low '
            'obstacles are seen nearer. 0 (the default): the plain min_obstacle_height; with '
            '1, `scanfuse evaluate` measured on the same drives false obstacles on slopes '
            '2.10 -> 1.78 % and recall on slopes 0.915 -> 0.904, but driving on it 2 of 30 '
            'terrain trials collided (docs/simulation.md)'
        ),
    )
    far_confirm_range: float = Field(
        1.5,
        ge=0.0,
        le=100.0,
        allow_inf_nan=False,
        description=(
            "obstacle method, with odometry: a camera's slab reading farther than this, metres, "
            'is kept only when its previous frame had one within 3 cm plus half a sigma of '
            'depth_noise of its place (far floor noise differs frame to frame, an obstacle '
            'stays); nearer ones at once; 0: every reading at once. A low obstacle moving '
            'faster than that tolerance a frame (0.6 m/s at 1.5 m, 15 Hz) is shown once '
            'nearer. 1.5 chosen by `scanfuse evaluate` (docs/simulation.md, its twenty-sixth '
            'round: terrain false obstacles on slopes 0.67 %; 1.0 gave 0.62 % but, turning, '
            'recall in view 0.963 -> 0.933)'
        ),
    )
    ground_estimate: bool = Field(
        default=True,
        description=(
            'obstacle method: find the floor in every depth frame (the mounting is the prior) '
            'and measure the slab and drops above it, so a pitching body or a mounting a few '
            "degrees off does not report the floor; off: heights above the mounting's plane"
        ),
    )
    ground_max_tilt: float = Field(
        math.radians(10.0),
        gt=0.0,
        lt=math.pi / 4,
        allow_inf_nan=False,
        description=(
            "radians the floor found in a frame may tilt from the mounting's plane: the "
            "steepest floor (max_slope, 7.1 deg) and the body's pitch on it (about 3 deg), so "
            'a robot at the foot of a 1:8 ramp sees the ramp as floor'
        ),
    )
    ground_max_offset: float = Field(
        0.08,
        ge=0.0,
        le=1.0,
        allow_inf_nan=False,
        description=(
            "metres the camera may be above or below the mounting's height over the floor found"
        ),
    )
    ground_smoothing: float = Field(
        0.3,
        gt=0.0,
        le=1.0,
        allow_inf_nan=False,
        description='weight of the newest frame in the smoothed floor (1: no smoothing)',
    )
    max_slope: float = Field(
        math.atan(1.0 / 8.0),
        ge=0.0,
        lt=math.pi / 4,
        allow_inf_nan=False,
        description=(
            'obstacle method with ground_estimate: radians of the steepest ground that is '
            'floor (a ramp, up or down; default 1:8); steeper ground, steps and drops are not; '
            '0: the floor is one plane'
        ),
    )
    ground_trail: bool = Field(
        default=True,
        description=(
            'obstacle method with an IMU and odometry: a LiDAR reading within 5 cm of the '
            'ground the robot drove over (kept 1 m either side of its path, 4 m around where it '
            'began; or of that ground raised by the drift of its summed height, as 20 readings '
            'of the scan show it) is the floor met by a pitched LiDAR plane, not an obstacle: '
            'it is dropped (NaN)'
        ),
    )
    camera_x: float = _metres(0.0, 'camera position in the base frame, metres')
    camera_y: float = _metres(0.0, 'camera position in the base frame, metres')
    camera_height: float = _metres(0.45, 'camera height above the floor, metres')
    camera_roll: float = _radians(0.0, 'camera roll, radians')
    camera_pitch: float = _radians(math.radians(20.0), 'camera pitch, radians, positive looks down')
    camera_yaw: float = _radians(0.0, 'camera yaw, radians, positive looks left')
    lidar_x: float = _metres(0.0, 'LiDAR position in the base frame, metres')
    lidar_y: float = _metres(0.0, 'LiDAR position in the base frame, metres')
    lidar_height: float = _metres(0.30, 'LiDAR height above the floor, metres')
    lidar_roll: float = _radians(
        0.0, 'LiDAR roll in the base frame, radians (pi: mounted upside down)'
    )
    lidar_pitch: float = _radians(0.0, 'LiDAR pitch in the base frame, radians')
    lidar_yaw: float = _radians(0.0, 'LiDAR yaw in the base frame, radians')
    assemble_fragments: bool = assemble_fragments_field()
    fragment_timeout: float = fragment_timeout_field()
    full_circle: bool = Field(
        default=False,
        description=(
            "output a 360-degree scan on the first LiDAR's increment, NaN where no source has "
            "a reading (a 270-degree LiDAR's blind sector, filled by another LiDAR or camera)"
        ),
    )
    output_frame: str = Field(
        '',
        description=(
            'frame of the output scan (any frame TF or the mountings reach: base_frame, a '
            "LiDAR's); every source's readings are re-binned into it from their 3D points. "
            "Empty: the first LiDAR's frame (no LiDAR: the camera's for the row method, else "
            'base_frame)'
        ),
    )
    angle_increment: float = Field(
        0.0,
        ge=0.0,
        le=math.pi,
        allow_inf_nan=False,
        description=(
            "output grid step, radians; 0: the first LiDAR's grid (no LiDAR: the row "
            "method's own, depthimage_to_laserscan's; else pi/360 over angle_min..angle_max)"
        ),
    )
    angle_min: float = Field(
        -math.pi,
        ge=-2.0 * math.pi,
        le=2.0 * math.pi,
        allow_inf_nan=False,
        description='first angle of the output grid, radians (with angle_increment or no LiDAR)',
    )
    angle_max: float = Field(
        math.pi,
        ge=-2.0 * math.pi,
        le=2.0 * math.pi,
        allow_inf_nan=False,
        description='last angle of the output grid, radians (with angle_increment or no LiDAR)',
    )
    output_range_min: float = Field(
        0.0,
        ge=0.0,
        le=MAX_RANGE,
        allow_inf_nan=False,
        description=(
            "output scan's range_min, metres (range_min is the depth camera's); a reading "
            "nearer is dropped (NaN, REP-117); 0: the sources' own"
        ),
    )
    output_range_max: float = Field(
        0.0,
        ge=0.0,
        le=MAX_RANGE,
        allow_inf_nan=False,
        description=(
            "output scan's range_max, metres; a reading farther is no return within range "
            "(+Inf, REP-117); 0: the sources' own"
        ),
    )
    trigger: str = Field(
        '',
        description=(
            "the named source whose messages make the outputs (its frame is output_frame's "
            'default); empty: the first LiDAR (no LiDAR: the first camera, else the first cloud)'
        ),
    )
    publish_rate: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        allow_inf_nan=False,
        description=(
            'Hz; 0: one output per scan of the first LiDAR; > 0: outputs stamped k / '
            'publish_rate, each the freshest scan (at most its max_time_offset old) moved to '
            'that stamp through odometry, the other sources paired with it as with a scan'
        ),
    )
    use_tf: bool = Field(
        default=True, description='take extrinsics from /tf_static and /tf when they are there'
    )
    base_frame: str = Field('base_link', description='robot frame whose z = 0 is the floor')
    max_time_offset: float = Field(
        0.1,
        gt=0.0,
        le=MAX_TIME_OFFSET,
        allow_inf_nan=False,
        description='largest LiDAR-to-depth stamp difference paired, seconds',
    )
    motion_compensation: bool = Field(
        default=True,
        description=(
            'with odometry, move the depth points from the camera stamp to the scan stamp '
            '(and de-skew the LiDAR when deskew is on)'
        ),
    )
    deskew: bool = Field(
        default=True,
        description='with odometry, move each LiDAR beam (stamp + i * time_increment) to the stamp',
    )
    max_odometry_extrapolation: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description=(
            'seconds past the newest odometry a pose may be extrapolated; beyond, the pair is '
            'not compensated and the LiDAR passes through'
        ),
    )
    odom_frame: str = Field('odom', description='odometry frame (REP-105) of TF odometry')
    odom_topic: str = Field('/odom', description='nav_msgs/Odometry topic')
    imu_topic: str = Field(
        '',
        description=(
            "sensor_msgs/Imu topic: the base's pitch and roll at each depth frame tilt the "
            "mounting's floor (the ground estimate's prior, or the floor with it off); "
            'empty: none (scanfuse bag takes the one Imu topic of a bag that holds one)'
        ),
    )
    memory: bool = Field(
        default=True,
        description=(
            'with odometry, remember camera obstacles in the odometry frame and keep them in '
            'the fused scan when the camera no longer sees them (only the camera clears them)'
        ),
    )
    memory_radius: float = Field(
        2.0,
        gt=0.0,
        le=MAX_MEMORY_RADIUS,
        description=(
            'metres around the robot obstacles are remembered; at most about 723 memory_cell '
            '(the grid holds 2^21 cells)'
        ),
    )
    memory_time: float = Field(
        20.0, gt=0.0, le=3600.0, description='seconds an obstacle is remembered unless re-seen'
    )
    memory_ages_while_stopped: bool = Field(
        default=True,
        description=(
            'false: memory_time counts only while the robot moves, so a robot held still '
            "beside a low obstacle out of the camera's view (stop zone, queue) keeps it"
        ),
    )
    memory_cell: float = Field(
        0.025, ge=0.005, le=0.5, description='metres: one remembered point per cell this size'
    )
    memory_odometry_timeout: float = Field(
        1.0,
        gt=0.0,
        le=60.0,
        description=(
            'seconds without usable odometry after which the memory is dropped (until then it '
            'is frozen: neither merged nor updated)'
        ),
    )
    memory_scan_matching: bool = Field(
        default=True,
        description=(
            'keep the memory aligned with the walls the LiDAR sees where wheel odometry drifts '
            '(each scan matched against an earlier one; refused matches fall back to odometry)'
        ),
    )
    camera_timeout: float = Field(
        0.5,
        gt=0.0,
        le=MAX_CAMERA_TIMEOUT,
        allow_inf_nan=False,
        description='camera silence after which the LiDAR passes through, seconds',
    )
    publish_depth_scan: bool = Field(
        default=True, description='also publish the depth scan on /scan_depth'
    )
    scan_topic: str = Field(
        '/scan', description='LiDAR LaserScan topic; empty: no LiDAR (a camera-only robot)'
    )
    depth_topic: str = Field(
        '/camera/depth/image_raw',
        description='depth Image topic; empty: no camera (LiDARs or clouds only)',
    )
    camera_info_topic: str = Field('/camera/depth/camera_info', description='CameraInfo topic')
    fused_topic: str = Field('/scan_fused', description='fused LaserScan topic')
    depth_scan_topic: str = Field('/scan_depth', description='depth LaserScan topic')
    instant_topic: str = Field(
        '/scan_fused_instant',
        description=(
            'fused LaserScan without the memory (for SLAM: measurements only); empty: not published'
        ),
    )
    memory_scan_topic: str = Field(
        '/scan_memory',
        description='LaserScan of the remembered obstacles alone (viewing); empty: not published',
    )

    sources: SourceSet = Field(
        default_factory=SourceSet,
        description='named LiDARs, cameras and clouds (see scanfuse.sources); empty: one of each',
    )

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
        for name, low, high in _own_slabs(self):
            if low >= high:
                msg = (
                    f'source {name}: its slab bottom ({low}) must be below its top ({high}) '
                    '(its own values, or min_obstacle_height / max_obstacle_height where it '
                    'sets none)'
                )
                raise ValueError(msg)
        side = memory_grid_side(self.memory_radius, self.memory_cell)
        if side * side > MAX_MEMORY_CELLS:
            msg = (
                f'memory_radius {self.memory_radius} m with memory_cell {self.memory_cell} m needs '
                f'{side * side} memory cells (at most {MAX_MEMORY_CELLS}): make memory_cell at '
                f'least {_smallest_cell(self.memory_radius):.4f} m or memory_radius smaller'
            )
            raise ValueError(msg)
        if not (self.has_lidar or self.has_camera or self.sources.clouds):
            msg = (
                'no source: scan_topic and depth_topic are empty and no cloud is named; '
                'give at least one LiDAR, depth camera or cloud'
            )
            raise ValueError(msg)
        if self.trigger:
            _check_trigger(self)
        if self.publish_rate > 0.0 and not self.has_lidar:
            msg = (
                'publish_rate moves LiDAR scans to its stamps and needs a LiDAR; without one '
                'every depth frame (or cloud) makes an output: set publish_rate: 0'
            )
            raise ValueError(msg)
        if 0.0 < self.output_range_max <= self.output_range_min:
            msg = (
                f'output_range_max ({self.output_range_max}) must be above output_range_min '
                f"({self.output_range_min}); 0 keeps the sources' own range_max"
            )
            raise ValueError(msg)
        if self.angle_increment > 0.0 and self.angle_max <= self.angle_min:
            msg = (
                f'angle_max ({self.angle_max}) must be above angle_min ({self.angle_min}) '
                'for the output grid'
            )
            raise ValueError(msg)
        if self.d2l_compat and self.scan_row is not None:
            msg = (
                'd2l_compat reproduces depthimage_to_laserscan, whose band is always centred '
                'on the principal point: leave scan_row unset or turn d2l_compat off'
            )
            raise ValueError(msg)
        return self

    @property
    def has_lidar(self) -> bool:
        """A LiDAR is configured (`scan_topic`, or the first named LiDAR, non-empty)."""
        return bool(self.scan_topic)

    @property
    def has_camera(self) -> bool:
        """A depth camera is configured (`depth_topic`, or the first named camera)."""
        return bool(self.depth_topic)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> FusionConfig:
        """Validate plain values; errors name every bad parameter.

        Named sources (`lidars: [...]` with a section per name) are gathered into `sources`;
        the first LiDAR and camera listed (the `trigger` one first) also fill the one-source
        parameters (topic and mounting), which then name those two among the sources.
        """
        values, named = split_sources(values)
        if named is not None:
            named = _trigger_first(named, values.get('trigger'))
            values = {**values, **_primary_from_sources(named), 'sources': named}
        try:
            return cls.model_validate(values)
        except ValidationError as err:
            problems = '; '.join(
                f'{".".join(str(p) for p in e["loc"]) or "config"}: {e["msg"]}{_hint(e)}'
                for e in err.errors()
            )
            msg = f'invalid scanfuse parameters: {problems}'
            raise ConfigError(msg) from err

    @classmethod
    def from_ros_params(cls, path: str | Path, node_name: str = NODE_NAME) -> FusionConfig:
        """Load `<node_name>: ros__parameters: {...}` (or `/**:`) from a ROS 2 parameter file.

        The node's own settings (`NODE_ONLY`) may be in it too and are left out.
        """
        values = read_ros_params(path, node_name)
        return cls.from_dict({k: v for k, v in values.items() if k not in NODE_ONLY})

    def to_ros_params(self, node_name: str = NODE_NAME) -> dict[str, Any]:
        """The parameter-file form of this configuration (loadable by ROS 2 and by us)."""
        values = self.model_dump(mode='json', exclude_none=True, exclude={'sources'})
        values.update(sources_to_params(self.sources))
        return {node_name: {'ros__parameters': values}}

    def with_changes(self, **changes: Any) -> FusionConfig:
        """A validated copy with some parameters changed."""
        current = self.model_dump(exclude={'sources'})
        current.update(sources_to_params(self.sources))
        return self.from_dict({**current, **changes})


_RANGE_ERRORS = frozenset({'less_than_equal', 'greater_than_equal', 'less_than', 'greater_than'})


def _hint(error: Any) -> str:
    """What the user most likely meant: the unit of an angle out of range (degrees given
    where radians are asked), the parameter nearest to a name that is none."""
    loc = error.get('loc') or ()
    name = str(loc[0]) if loc else ''
    if error.get('type') == 'extra_forbidden':
        guess = difflib.get_close_matches(name, list(FusionConfig.model_fields), n=1, cutoff=0.6)
        return f' (did you mean {guess[0]}?)' if guess else ''
    field = FusionConfig.model_fields.get(name)
    value = error.get('input')
    described = field.description or '' if field is not None else ''
    if (
        error.get('type') in _RANGE_ERRORS
        and 'radians' in described
        and isinstance(value, int | float)
        and not isinstance(value, bool)
    ):
        return f' (radians: {value:g} deg = {math.radians(value):.3f})'
    return ''


def _trigger_first(named: dict[str, Any], trigger: object) -> dict[str, Any]:
    """The source lists with the `trigger` source first in its own (the first of a kind is
    the one that triggers); unchanged when no listed source has that name."""
    if not trigger:
        return named
    out = dict(named)
    for kind in ('lidars', 'cameras', 'clouds'):
        items = named.get(kind)
        if not isinstance(items, list):
            continue
        chosen = [item for item in items if isinstance(item, dict) and item.get('name') == trigger]
        if chosen:
            out[kind] = chosen + [item for item in items if item is not chosen[0]]
    return out


def _check_trigger(config: FusionConfig) -> None:
    """ValueError unless `trigger` names the source that makes the outputs: a LiDAR, or
    without a LiDAR a camera, or with neither a cloud."""
    sources, trigger = config.sources, config.trigger
    names = {
        'lidars': [s.name for s in sources.lidars],
        'cameras': [s.name for s in sources.cameras],
        'clouds': [s.name for s in sources.clouds],
    }
    kind = next((kind for kind, listed in names.items() if trigger in listed), None)
    if kind is None:
        every = [name for listed in names.values() for name in listed]
        msg = (
            f'trigger {trigger!r} is no named source (named: {", ".join(every) or "none"}); '
            'name one of them, or leave trigger empty for the first LiDAR'
        )
        raise ValueError(msg)
    if kind == 'cameras' and config.has_lidar:
        msg = (
            f'trigger {trigger!r} is a camera: a camera makes the outputs only on a robot '
            "without a LiDAR (scan_topic: '' and no lidars); name a LiDAR"
        )
        raise ValueError(msg)
    if kind == 'clouds' and (config.has_lidar or config.has_camera):
        msg = (
            f'trigger {trigger!r} is a cloud: a cloud makes the outputs only on a robot '
            "without LiDAR and camera (scan_topic: '', depth_topic: ''); name a LiDAR"
        )
        raise ValueError(msg)


def _own_slabs(config: FusionConfig) -> list[tuple[str, float, float]]:
    """(name, bottom, top) of every camera's and cloud's slab: its own, or the global one."""
    low, high = config.min_obstacle_height, config.max_obstacle_height
    slabs = [
        (
            camera.name,
            low if camera.min_obstacle_height is None else camera.min_obstacle_height,
            high if camera.max_obstacle_height is None else camera.max_obstacle_height,
        )
        for camera in config.sources.cameras
    ]
    slabs += [
        (
            cloud.name,
            low if cloud.min_height is None else cloud.min_height,
            high if cloud.max_height is None else cloud.max_height,
        )
        for cloud in config.sources.clouds
    ]
    return slabs


def _smallest_cell(radius: float) -> float:
    """The smallest memory_cell (to 0.1 mm, rounded up) whose grid fits `radius`."""
    cell = 2.0 * radius / (math.isqrt(MAX_MEMORY_CELLS) - 3)
    return math.ceil(cell * 1e4) / 1e4


def _primary_from_sources(named: dict[str, Any]) -> dict[str, Any]:
    """The one-source parameters the first named LiDAR and camera stand for."""
    primary: dict[str, Any] = {}
    lidars, cameras = named.get('lidars') or [], named.get('cameras') or []
    if lidars and isinstance(lidars[0], dict):
        first = lidars[0]
        primary['scan_topic'] = first.get('topic')
        for axis, name in (('x', 'lidar_x'), ('y', 'lidar_y'), ('z', 'lidar_height')):
            primary[name] = first.get(axis, 0.0)
        for angle in ('roll', 'pitch', 'yaw'):
            primary[f'lidar_{angle}'] = first.get(angle, 0.0)
        for name in ('assemble_fragments', 'fragment_timeout'):
            if name in first:
                primary[name] = first[name]
    if cameras and isinstance(cameras[0], dict):
        first = cameras[0]
        primary['depth_topic'] = first.get('depth_topic')
        primary['camera_info_topic'] = first.get('camera_info_topic')
        for axis, name in (('x', 'camera_x'), ('y', 'camera_y'), ('z', 'camera_height')):
            primary[name] = first.get(axis, 0.0)
        for angle in ('roll', 'pitch', 'yaw'):
            primary[f'camera_{angle}'] = first.get(angle, 0.0)
    return {key: value for key, value in primary.items() if value is not None}


def read_ros_params(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """The `ros__parameters` of `node_name` in a ROS 2 parameter file.

    At most MAX_PARAMS_BYTES are read and MAX_PARAMS_DEPTH levels nested; YAML aliases are
    refused, as ROS 2's own parameter parser refuses them (one alias can stand for gigabytes:
    the "billion laughs").
    """
    path = Path(path)
    try:
        with path.open('rb') as file:
            data = file.read(MAX_PARAMS_BYTES + 1)
    except OSError as err:
        msg = f'cannot read parameter file {path}: {err.strerror}'
        raise ConfigError(msg) from err
    if len(data) > MAX_PARAMS_BYTES:
        msg = (
            f'parameter file {path} is larger than {MAX_PARAMS_BYTES // 1024} KiB; '
            'is it a parameter file?'
        )
        raise ConfigError(msg)
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as err:
        msg = f'parameter file {path} is not UTF-8 text (byte {err.start}): {err.reason}'
        raise ConfigError(msg) from err
    try:
        _check_yaml_shape(path, text)
        document = yaml.safe_load(text)
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


def _check_yaml_shape(path: Path, text: str) -> None:
    """Refuse aliases and nesting deeper than MAX_PARAMS_DEPTH, from the event stream (which
    needs no recursion, unlike the loader that would meet them)."""
    depth = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        line = event.start_mark.line + 1 if event.start_mark is not None else '?'
        if isinstance(event, yaml.AliasEvent):
            msg = (
                f'parameter file {path} uses a YAML alias (line {line}); '
                "ROS 2's parameter parser refuses them too: write the values out"
            )
            raise ConfigError(msg)
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_PARAMS_DEPTH:
                msg = (
                    f'parameter file {path} nests more than {MAX_PARAMS_DEPTH} levels deep '
                    f'(line {line}); is it a parameter file?'
                )
                raise ConfigError(msg)
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
