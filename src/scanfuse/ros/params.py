"""The node's ROS parameters: every `FusionConfig` field, plus the node's own few.

Plain data here (names, types, ranges, whether a change is safe while running);
`scanfuse.ros.node` turns it into rclpy `ParameterDescriptor`s. Values always
pass through `FusionConfig.from_dict`, so a parameter set at run time is
validated exactly as a parameter file is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any

from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError

# scan_row None ("the principal-point row") as a ROS integer parameter.
SCAN_ROW_CENTRE = -1

# Changing these while running would need new subscriptions or publishers.
START_UP_ONLY = frozenset(
    {
        'scan_topic',
        'depth_topic',
        'camera_info_topic',
        'fused_topic',
        'depth_scan_topic',
        'odom_topic',
        'publish_depth_scan',
    }
)

# Inclusive ranges shown by `ros2 param describe` and enforced by rclpy.
RANGES: dict[str, tuple[float, float]] = {
    'scan_row': (SCAN_ROW_CENTRE, 100_000),
    'scan_height': (1, 100_000),
    'floor_margin': (0.0, 5.0),
    'range_min': (0.0, 100.0),
    'range_max': (0.01, 1000.0),
    'min_obstacle_height': (-5.0, 5.0),
    'max_obstacle_height': (-5.0, 5.0),
    'camera_x': (-10.0, 10.0),
    'camera_y': (-10.0, 10.0),
    'camera_height': (-10.0, 10.0),
    'camera_roll': (-math.pi, math.pi),
    'camera_pitch': (-math.pi / 2, math.pi / 2),
    'camera_yaw': (-math.pi, math.pi),
    'lidar_x': (-10.0, 10.0),
    'lidar_y': (-10.0, 10.0),
    'lidar_height': (-10.0, 10.0),
    'lidar_yaw': (-math.pi, math.pi),
    'max_time_offset': (0.001, 5.0),
    'camera_timeout': (0.01, 60.0),
    'pair_wait': (0.0, 1.0),
    'lidar_timeout': (0.05, 60.0),
}


class Kind(str, Enum):
    """ROS parameter types used."""

    BOOL = 'bool'
    INTEGER = 'integer'
    DOUBLE = 'double'
    STRING = 'string'


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter."""

    name: str
    kind: Kind
    default: Any
    description: str
    start_up_only: bool
    choices: tuple[str, ...] = ()

    @property
    def value_range(self) -> tuple[float, float] | None:
        return RANGES.get(self.name)

    @property
    def constraints(self) -> str:
        """Free text for `ParameterDescriptor.additional_constraints`."""
        parts = []
        if self.choices:
            parts.append(f'one of: {", ".join(self.choices)}')
        if self.name == 'scan_row':
            parts.append(f'{SCAN_ROW_CENTRE} means the principal-point row')
        if self.start_up_only:
            parts.append('read at start-up; restart the node to change it')
        return '; '.join(parts)


@dataclass(frozen=True)
class NodeSettings:
    """The node's own parameters (not part of the fusion)."""

    pair_wait: float = 0.0
    lidar_timeout: float = 1.0


NODE_PARAMS = (
    ParamSpec(
        'pair_wait',
        Kind.DOUBLE,
        NodeSettings.pair_wait,
        'longest a scan waits for a depth frame stamped at or after it, seconds; '
        '0 pairs with the frames already received (lowest latency), '
        'a frame period or more pairs exactly as `scanfuse bag` does',
        start_up_only=False,
    ),
    ParamSpec(
        'lidar_timeout',
        Kind.DOUBLE,
        NodeSettings.lidar_timeout,
        'LiDAR silence after which /diagnostics reports ERROR, seconds',
        start_up_only=False,
    ),
)


def _kind(value: Any) -> Kind:
    if isinstance(value, bool):
        return Kind.BOOL
    if isinstance(value, int):
        return Kind.INTEGER
    if isinstance(value, float):
        return Kind.DOUBLE
    return Kind.STRING


def to_ros_value(name: str, value: Any) -> Any:
    """A `FusionConfig` value as a ROS parameter value."""
    if name == 'scan_row' and value is None:
        return SCAN_ROW_CENTRE
    if isinstance(value, Enum):
        return value.value
    return value


def fusion_param_specs(defaults: FusionConfig) -> list[ParamSpec]:
    """One spec per `FusionConfig` field, its default taken from `defaults`."""
    specs = []
    for name, info in FusionConfig.model_fields.items():
        value = to_ros_value(name, getattr(defaults, name))
        annotation = info.annotation
        choices = (
            tuple(str(member.value) for member in annotation)
            if isinstance(annotation, type) and issubclass(annotation, Enum)
            else ()
        )
        kind = Kind.INTEGER if name == 'scan_row' else _kind(value)
        specs.append(
            ParamSpec(
                name,
                kind,
                value,
                info.description or name,
                start_up_only=name in START_UP_ONLY,
                choices=choices,
            )
        )
    return specs


def all_param_specs(
    defaults: FusionConfig, settings: NodeSettings | None = None
) -> list[ParamSpec]:
    settings = settings or NodeSettings()
    node_specs = [
        ParamSpec(
            spec.name,
            spec.kind,
            getattr(settings, spec.name),
            spec.description,
            spec.start_up_only,
        )
        for spec in NODE_PARAMS
    ]
    return [*fusion_param_specs(defaults), *node_specs]


def config_from_ros(values: dict[str, Any]) -> FusionConfig:
    """A validated `FusionConfig` from ROS parameter values (ConfigError names what is wrong)."""
    fusion = {name: values[name] for name in FusionConfig.model_fields if name in values}
    if fusion.get('scan_row') == SCAN_ROW_CENTRE:
        fusion['scan_row'] = None
    return FusionConfig.from_dict(fusion)


def settings_from_ros(values: dict[str, Any]) -> NodeSettings:
    defaults = NodeSettings()
    settings = NodeSettings(
        pair_wait=float(values.get('pair_wait', defaults.pair_wait)),
        lidar_timeout=float(values.get('lidar_timeout', defaults.lidar_timeout)),
    )
    for name in ('pair_wait', 'lidar_timeout'):
        low, high = RANGES[name]
        value = getattr(settings, name)
        if not low <= value <= high:
            msg = f'{name} must be in [{low}, {high}], got {value}'
            raise ConfigError(msg)
    return settings


def check_change(current: dict[str, Any], changes: dict[str, Any]) -> str | None:
    """Why `changes` cannot be applied to a running node, or None when they can."""
    fixed = sorted(
        name for name in changes if name in START_UP_ONLY and changes[name] != current[name]
    )
    if fixed:
        return (
            f'{", ".join(fixed)} can only be set at start-up (topics and publishers are '
            'created then); restart the node with the new value or remap the topic '
            '(--ros-args -r /scan:=/my_scan)'
        )
    merged = {**current, **changes}
    try:
        config_from_ros(merged)
        settings_from_ros(merged)
    except ConfigError as err:
        return str(err)
    return None
