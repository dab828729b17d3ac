"""The node's ROS parameters: every `FusionConfig` field, plus the node's own few.

Plain data here (names, types, ranges, whether a change is safe while running);
`scanfuse.ros.node` turns it into rclpy `ParameterDescriptor`s and `scanfuse params`
into docs/parameters.md. Values always pass through `FusionConfig.from_dict`, so a
parameter set at run time is validated exactly as a parameter file is.

Bounds have one home: the pydantic `Field`s (`ge`, `gt`, `le`, `lt`) of `FusionConfig`
and `NodeSettings`. `DESCRIPTOR_LIMITS` only closes a side a Field leaves open, because an
rclpy range needs both ends; a test fails when it restates a side a Field bounds.

    python -m scanfuse.cli params --output docs/parameters.md   (or `scanfuse params ...`)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from enum import Enum
from typing import TYPE_CHECKING, Any

import annotated_types
from pydantic import BaseModel, ConfigDict, Field

from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.sources import KINDS, CameraSource, CloudSource, LidarSource

if TYPE_CHECKING:
    from pydantic.fields import FieldInfo

# scan_row None ("the principal-point row") as a ROS integer parameter.
SCAN_ROW_CENTRE = -1

# Declared by the node from the source lists, not one parameter each (see scanfuse.sources).
NESTED = frozenset({'sources'})
# Changing these while running would need new subscriptions or publishers.
START_UP_ONLY = frozenset(
    {
        'scan_topic',
        'depth_topic',
        'camera_info_topic',
        'fused_topic',
        'depth_scan_topic',
        'odom_topic',
        'imu_topic',
        'instant_topic',
        'memory_scan_topic',
        'publish_depth_scan',
        'trigger',  # which source's topic is subscribed as the trigger
    }
)

# (low, high) for the sides of a parameter that its Field leaves open (None: the Field's side).
# rclpy ranges are inclusive and need both ends: these make `ros2 param describe` and rclpy's
# checks of `-p` overrides cover every numeric parameter that has a sensible limit.
DESCRIPTOR_LIMITS: dict[str, tuple[float | None, float | None]] = {
    'scan_row': (None, 100_000),
    'scan_height': (None, 100_000),
}


class Kind(str, Enum):
    """ROS parameter types used."""

    BOOL = 'bool'
    INTEGER = 'integer'
    DOUBLE = 'double'
    STRING = 'string'
    STRING_ARRAY = 'string array'


@dataclass(frozen=True)
class Bounds:
    """The limits of one numeric parameter; a side is None when unbounded."""

    low: float | None = None
    high: float | None = None
    low_exclusive: bool = False
    high_exclusive: bool = False

    @property
    def inclusive(self) -> tuple[float, float] | None:
        """The rclpy range (always inclusive), when both sides are known.

        An exclusive side (`gt=0`) becomes its inclusive end: rclpy lets the end value
        through and `FusionConfig` refuses it with a message.
        """
        if self.low is None or self.high is None:
            return None
        return (self.low, self.high)

    def contains(self, value: float) -> bool:
        if self.low is not None and (
            value < self.low or (self.low_exclusive and value == self.low)
        ):
            return False
        return self.high is None or not (
            value > self.high or (self.high_exclusive and value == self.high)
        )

    def text(self, number: Any = str) -> str:
        """Interval notation: `[0.0, 1.0]`, `(0.0, 5.0]`, `>= 1`, `> 0.0`, or ''."""
        if self.low is not None and self.high is not None:
            left = '(' if self.low_exclusive else '['
            right = ')' if self.high_exclusive else ']'
            return f'{left}{number(self.low)}, {number(self.high)}{right}'
        if self.low is not None:
            return f'{">" if self.low_exclusive else ">="} {number(self.low)}'
        if self.high is not None:
            return f'{"<" if self.high_exclusive else "<="} {number(self.high)}'
        return ''


def _bound(value: Any) -> float:
    """A Field's limit as a number; integers stay integers (they are shown and sent as such)."""
    return value if isinstance(value, int) else float(value)


def field_bounds(info: FieldInfo) -> Bounds:
    """The `ge`/`gt`/`le`/`lt` of a pydantic Field."""
    bounds = Bounds()
    for item in info.metadata:
        if isinstance(item, annotated_types.Ge):
            bounds = replace(bounds, low=_bound(item.ge), low_exclusive=False)
        elif isinstance(item, annotated_types.Gt):
            bounds = replace(bounds, low=_bound(item.gt), low_exclusive=True)
        elif isinstance(item, annotated_types.Le):
            bounds = replace(bounds, high=_bound(item.le), high_exclusive=False)
        elif isinstance(item, annotated_types.Lt):
            bounds = replace(bounds, high=_bound(item.lt), high_exclusive=True)
    return bounds


def parameter_bounds(name: str, info: FieldInfo) -> Bounds:
    """A parameter's bounds: its Field's, with `DESCRIPTOR_LIMITS` on the sides left open."""
    bounds = field_bounds(info)
    extra_low, extra_high = DESCRIPTOR_LIMITS.get(name, (None, None))
    if bounds.low is None and extra_low is not None:
        bounds = replace(bounds, low=extra_low, low_exclusive=False)
    if bounds.high is None and extra_high is not None:
        bounds = replace(bounds, high=extra_high, high_exclusive=False)
    if name == 'scan_row' and bounds.low is not None:
        # The ROS parameter also takes SCAN_ROW_CENTRE, its encoding of None.
        bounds = replace(bounds, low=SCAN_ROW_CENTRE, low_exclusive=False)
    return bounds


# Units named in the descriptions (REP-103), most specific first.
_UNITS = (
    (re.compile(r'\b1/m\b'), '1/m'),
    (re.compile(r'\bradians\b'), 'rad'),
    (re.compile(r'\bmetres\b'), 'm'),
    (re.compile(r'\bseconds\b'), 's'),
)


def unit_of(description: str) -> str:
    """The unit a description names ('metres' -> 'm', ...), or '' when it names none."""
    for pattern, unit in _UNITS:
        if pattern.search(description):
            return unit
    return ''


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter."""

    name: str
    kind: Kind
    default: Any
    description: str
    start_up_only: bool
    choices: tuple[str, ...] = ()
    bounds: Bounds = Bounds()
    node_only_bounds: bool = False  # bounds differ from the Field's (DESCRIPTOR_LIMITS, scan_row)

    @property
    def value_range(self) -> tuple[float, float] | None:
        """Inclusive range for the descriptor (None for non-numbers and one-sided bounds)."""
        if self.kind not in (Kind.INTEGER, Kind.DOUBLE):
            return None
        return self.bounds.inclusive

    @property
    def unit(self) -> str:
        return unit_of(self.description) if self.kind in (Kind.INTEGER, Kind.DOUBLE) else ''

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


class NodeSettings(BaseModel):
    """The node's own parameters (not part of the fusion)."""

    model_config = ConfigDict(frozen=True, extra='forbid')

    pair_wait: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description=(
            'longest a scan waits for a depth frame stamped at or after it, seconds; '
            '0 pairs with the frames already received (lowest latency), '
            'a frame period or more pairs exactly as `scanfuse bag` does'
        ),
    )
    lidar_timeout: float = Field(
        1.0,
        ge=0.05,
        le=60.0,
        description='LiDAR silence after which /diagnostics reports ERROR, seconds',
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


def _model_param_specs(model: BaseModel) -> list[ParamSpec]:
    """One spec per field of a settings model, its default taken from `model`."""
    specs = []
    for name, info in type(model).model_fields.items():
        if name in NESTED:
            continue
        value = to_ros_value(name, getattr(model, name))
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
                bounds=parameter_bounds(name, info),
                node_only_bounds=parameter_bounds(name, info) != field_bounds(info),
            )
        )
    return specs


def fusion_param_specs(defaults: FusionConfig) -> list[ParamSpec]:
    """One spec per `FusionConfig` field, its default taken from `defaults`."""
    return _model_param_specs(defaults)


def all_param_specs(
    defaults: FusionConfig, settings: NodeSettings | None = None
) -> list[ParamSpec]:
    """Every parameter the node declares: the fusion's, then the node's own."""
    return [*_model_param_specs(defaults), *_model_param_specs(settings or NodeSettings())]


# ---------------------------------------------------------------- named sources

SOURCE_MODELS: dict[str, type[BaseModel]] = {
    'lidars': LidarSource,
    'cameras': CameraSource,
    'clouds': CloudSource,
}
# A source's fields that name topics: subscriptions are made at start-up.
SOURCE_TOPIC_FIELDS = frozenset({'topic', 'depth_topic', 'camera_info_topic'})
_LIST_DESCRIPTIONS = {
    'lidars': 'names of the LiDAR sources (the first triggers every output scan), each with '
    'a section NAME.topic, NAME.x, ...; empty: scan_topic alone',
    'cameras': 'names of the depth camera sources, each with a section NAME.depth_topic, '
    'NAME.camera_info_topic, ...; empty: depth_topic alone',
    'clouds': 'names of the PointCloud2 sources, each with a section NAME.topic, ...',
}


def _annotation_kind(annotation: Any) -> Kind:
    """The ROS type of a source field: `float | None` is a double that may stay unset."""
    if annotation is bool:
        return Kind.BOOL
    if annotation is int:
        return Kind.INTEGER
    if annotation is str:
        return Kind.STRING
    return Kind.DOUBLE


def source_list_spec(kind: str, names: list[str]) -> ParamSpec:
    """The `lidars` / `cameras` / `clouds` parameter (a string array)."""
    return ParamSpec(kind, Kind.STRING_ARRAY, names, _LIST_DESCRIPTIONS[kind], start_up_only=True)


def source_param_specs(kind: str, name: str, section: BaseModel | None) -> list[ParamSpec]:
    """`NAME.field` for every field of a source's model (`scanfuse.sources`).

    Defaults are the section's values when the parameter file has one, else the Field's;
    a required field (a topic) defaults to '' and `config_from_ros` leaves it out, so the
    config says it is missing. An optional field (`min_height`) defaults to unset (None).
    """
    specs = []
    for field, info in SOURCE_MODELS[kind].model_fields.items():
        if field == 'name':
            continue
        if section is not None:
            value = getattr(section, field)
        else:
            value = '' if info.is_required() else info.default
        specs.append(
            ParamSpec(
                f'{name}.{field}',
                _annotation_kind(info.annotation),
                value,
                info.description or field,
                start_up_only=field in SOURCE_TOPIC_FIELDS,
                bounds=field_bounds(info),
            )
        )
    return specs


def _start_up_only(name: str) -> bool:
    if name in START_UP_ONLY or name in KINDS:
        return True
    return '.' in name and name.split('.', 1)[1] in SOURCE_TOPIC_FIELDS


def config_from_ros(values: dict[str, Any]) -> FusionConfig:
    """A validated `FusionConfig` from ROS parameter values (ConfigError names what is wrong)."""
    fusion = {
        name: list(value) if name in KINDS else value
        for name, value in values.items()
        if name in FusionConfig.model_fields
        or name in KINDS
        # An unset optional field (None) or an unset topic ('') is left to its model.
        or ('.' in name and value is not None and value != '')
    }
    if fusion.get('scan_row') == SCAN_ROW_CENTRE:
        fusion['scan_row'] = None
    return FusionConfig.from_dict(fusion)


def settings_from_ros(values: dict[str, Any]) -> NodeSettings:
    """The node's own settings from ROS parameter values (ConfigError names what is wrong)."""
    chosen = {}
    for name, info in NodeSettings.model_fields.items():
        if name not in values:
            continue
        value = float(values[name])
        bounds = field_bounds(info)
        if not bounds.contains(value):
            msg = f'{name} must be in {bounds.text()}, got {value}'
            raise ConfigError(msg)
        chosen[name] = value
    return NodeSettings(**chosen)


def check_change(current: dict[str, Any], changes: dict[str, Any]) -> str | None:
    """Why `changes` cannot be applied to a running node, or None when they can."""
    fixed = sorted(
        name for name in changes if _start_up_only(name) and changes[name] != current.get(name)
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


# ---------------------------------------------------------------- the parameter table

REGENERATE = 'scanfuse params --output docs/parameters.md'


def _number(value: float) -> str:
    """A bound or default as people write it: 0.05, 3.0, 100000, -π/2."""
    if isinstance(value, int):
        return str(value)
    for multiple, name in ((0.5, 'π/2'), (1.0, 'π'), (2.0, '2π')):
        if math.isclose(abs(value), multiple * math.pi, rel_tol=1e-12):
            return f'-{name}' if value < 0 else name
    return f'{value:.1f}' if value.is_integer() else f'{value:g}'


def _default(spec: ParamSpec) -> str:
    if spec.kind is Kind.BOOL:
        return f'`{str(spec.default).lower()}`'
    if spec.kind is Kind.STRING:
        return f'`{spec.default}`'
    return f'`{_number(spec.default)}`'


def _range(spec: ParamSpec) -> str:
    if spec.choices:
        return ' | '.join(f'`{choice}`' for choice in spec.choices)
    text = spec.bounds.text(_number)
    return f'{text} *' if text and spec.node_only_bounds else text


def _cell(text: str) -> str:
    return text.replace('|', '\\|').replace('\n', ' ')


def markdown_table(specs: list[ParamSpec]) -> str:
    """A markdown table: name, default, range, unit, start-up only, description."""
    lines = [
        '| parameter | default | range | unit | start-up only | description |',
        '| --- | --- | --- | --- | --- | --- |',
    ]
    for spec in specs:
        description = spec.description
        if spec.name == 'scan_row':
            description += f'; {SCAN_ROW_CENTRE} means the principal-point row'
        cells = (
            f'`{spec.name}`',
            _default(spec),
            _range(spec),
            spec.unit,
            'yes' if spec.start_up_only else '',
            description,
        )
        lines.append('| ' + ' | '.join(_cell(cell) for cell in cells) + ' |')
    return '\n'.join(lines) + '\n'


def parameters_markdown() -> str:
    """docs/parameters.md: every parameter of the node with its defaults."""
    intro = (
        '# Parameters\n'
        '\n'
        'Every parameter the `scanfuse` node declares (`ros2 param describe /scanfuse NAME` '
        'shows the same), with its default. A parameter file (`scanfuse: ros__parameters:`) '
        'takes the same names, for the node and for `scanfuse bag --params`. Angles are '
        'radians, lengths metres (REP-103). Ranges are inclusive where written with `[ ]`, '
        "exclusive where written with `( )`. Ranges marked * are the node's only: its "
        'descriptors close a side that `FusionConfig` leaves open, so rclpy refuses values '
        'outside them but `scanfuse bag` does not. Start-up only: read when the node starts '
        '(topics, publishers); a change at run time is refused.\n'
        '\n'
        f'Generated from `FusionConfig` and `NodeSettings` by `{REGENERATE}`; do not edit by '
        'hand (tests/test_params_table.py fails when this file is stale).\n'
        '\n'
    )
    return intro + markdown_table(all_param_specs(FusionConfig()))
