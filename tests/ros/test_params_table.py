"""One home for every parameter's bounds and description, and the table made from it.

The bounds live in the pydantic Fields of `FusionConfig` and `NodeSettings`;
`DESCRIPTOR_LIMITS` only closes the sides those leave open (rclpy ranges need both
ends). docs/parameters.md is generated from the same place and must be current.
"""

from __future__ import annotations

import math

import pytest
from pydantic import BaseModel, Field

from scanfuse.cli import main
from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.ros import params
from scanfuse.ros.params import (
    DESCRIPTOR_LIMITS,
    REGENERATE,
    SCAN_ROW_CENTRE,
    Bounds,
    Kind,
    NodeSettings,
    ParamSpec,
    all_param_specs,
    field_bounds,
    parameters_markdown,
    settings_from_ros,
    unit_of,
)
from tests.support import REPOSITORY

TABLE = REPOSITORY / 'docs' / 'parameters.md'


class _Example(BaseModel):
    half_open: float = Field(1.0, gt=0.0, le=5.0)
    at_least_one: int = Field(1, ge=1)
    free: float = 0.0


def specs() -> dict:
    return {spec.name: spec for spec in all_param_specs(FusionConfig())}


# ---------------------------------------------------------------- bounds


def test_field_bounds_read_ge_gt_le_lt():
    half_open = field_bounds(_Example.model_fields['half_open'])
    assert half_open == Bounds(0.0, 5.0, low_exclusive=True, high_exclusive=False)
    assert half_open.text() == '(0.0, 5.0]'
    # rclpy ranges are inclusive: (0, 5] is sent as [0, 5]; FusionConfig refuses the 0.
    assert half_open.inclusive == (0.0, 5.0)
    assert [half_open.contains(v) for v in (0.0, 1e-9, 5.0, 5.000001)] == [
        False,
        True,
        True,
        False,
    ]
    at_least_one = field_bounds(_Example.model_fields['at_least_one'])
    assert at_least_one == Bounds(1, None)
    assert isinstance(at_least_one.low, int)  # an integer parameter gets an integer range
    assert at_least_one.text() == '>= 1'
    assert at_least_one.inclusive is None  # one side only: no rclpy range
    assert field_bounds(_Example.model_fields['free']) == Bounds()


def test_descriptor_limits_never_restate_a_side_the_field_bounds():
    for name, (low, high) in DESCRIPTOR_LIMITS.items():
        assert name in FusionConfig.model_fields, f'DESCRIPTOR_LIMITS names no parameter {name}'
        field = field_bounds(FusionConfig.model_fields[name])
        # After FusionConfig gains a bound, its entry here is stale: remove that side.
        assert low is None or field.low is None, f"{name}: the low side is the Field's"
        assert high is None or field.high is None, f"{name}: the high side is the Field's"


def test_ranges_come_from_the_fields_and_close_open_sides():
    declared = specs()
    # Field ge=0, le=1 and no descriptor limit: the node's range is the Field's.
    assert declared['max_odometry_extrapolation'].bounds == Bounds(0.0, 1.0)
    assert declared['max_odometry_extrapolation'].value_range == (0.0, 1.0)
    assert not declared['max_odometry_extrapolation'].node_only_bounds
    # Field ge=1, DESCRIPTOR_LIMITS closes the top: the node's range, not FusionConfig's.
    assert declared['scan_height'].value_range == (1, 100_000)
    assert declared['scan_height'].node_only_bounds
    # Field ge=0 for a row; the ROS parameter also takes -1 (the principal-point row).
    assert declared['scan_row'].value_range == (SCAN_ROW_CENTRE, 100_000)
    # gt=0: rclpy's inclusive range starts at 0, FusionConfig refuses the 0 itself.
    assert declared['range_max'].bounds.low_exclusive
    assert declared['range_max'].value_range == (0.0, 1000.0)
    # Node settings from NodeSettings' Fields.
    assert declared['pair_wait'].value_range == (0.0, 1.0)
    assert declared['lidar_timeout'].value_range == (0.05, 60.0)
    for spec in declared.values():
        if spec.kind in (Kind.BOOL, Kind.STRING):
            assert spec.value_range is None, spec.name
        else:
            assert spec.bounds.low is not None, f'{spec.name} has no lower bound'


def test_one_sided_bounds_give_no_rclpy_range():
    bounds = Bounds(1, None)
    assert bounds.inclusive is None
    spec = ParamSpec('k', Kind.INTEGER, 16, 'points', start_up_only=False, bounds=bounds)
    assert spec.value_range is None  # FusionConfig still refuses 0


def test_descriptors_carry_the_ranges_rclpy_enforces():
    pytest.importorskip('rclpy')
    from scanfuse.ros.node import descriptor

    declared = specs()
    row = descriptor(declared['scan_row']).integer_range[0]
    assert (row.from_value, row.to_value) == (SCAN_ROW_CENTRE, 100_000)
    extrapolation = descriptor(declared['max_odometry_extrapolation']).floating_point_range[0]
    assert (extrapolation.from_value, extrapolation.to_value) == (0.0, 1.0)
    one_sided = ParamSpec('k', Kind.INTEGER, 16, 'k', start_up_only=False, bounds=Bounds(1, None))
    assert list(descriptor(one_sided).integer_range) == []
    assert list(descriptor(declared['base_frame']).floating_point_range) == []


def test_node_settings_outside_their_field_bounds_are_refused():
    with pytest.raises(ConfigError, match=r'lidar_timeout must be in \[0\.05, 60\.0\], got 0\.01'):
        settings_from_ros({'lidar_timeout': 0.01})
    assert settings_from_ros({'pair_wait': 0.25}) == NodeSettings(pair_wait=0.25)
    assert settings_from_ros({}) == NodeSettings()


# ---------------------------------------------------------------- units and the table


def test_units_are_the_ones_the_descriptions_name():
    assert unit_of('camera roll, radians') == 'rad'
    assert unit_of('LiDAR height above the floor, metres') == 'm'
    assert unit_of('camera silence after which the LiDAR passes through, seconds') == 's'
    assert unit_of('as this * r^2 metres (1/m; stereo noise ...)') == '1/m'  # 1/m first
    assert unit_of('rows in the band of the row method') == ''
    declared = specs()
    assert declared['range_max'].unit == 'm'
    assert declared['camera_pitch'].unit == 'rad'
    assert declared['max_time_offset'].unit == 's'
    assert declared['obstacle_cluster_spread'].unit == '1/m'
    assert declared['obstacle_min_points'].unit == ''
    assert declared['base_frame'].unit == ''  # strings have none, whatever the text says


def test_the_table_has_one_row_per_declared_parameter():
    rows = [line for line in parameters_markdown().splitlines() if line.startswith('| `')]
    names = [row.split('`')[1] for row in rows]
    assert names == list(specs())
    by_name = dict(zip(names, rows, strict=True))
    cells = [cell.strip() for cell in by_name['fused_topic'].strip('|').split(' | ')]
    assert cells == ['`fused_topic`', '`/scan_fused`', '', '', 'yes', 'fused LaserScan topic']
    cells = [cell.strip() for cell in by_name['max_odometry_extrapolation'].strip('|').split(' | ')]
    assert cells[:5] == ['`max_odometry_extrapolation`', '`0.1`', '[0.0, 1.0]', 's', '']
    cells = [cell.strip() for cell in by_name['scan_height'].strip('|').split(' | ')]
    # ge=1 from the Field, 100000 from DESCRIPTOR_LIMITS: marked * (the node's only).
    assert cells[:4] == ['`scan_height`', '`1`', '[1, 100000] *', '']
    assert '`row` \\| `obstacle`' in by_name['method']
    assert Bounds(-math.pi / 2, math.pi).text(params._number) == '[-π/2, π]'
    assert Bounds(0.0, None, low_exclusive=True).text(params._number) == '> 0.0'


def test_docs_parameters_md_is_current():
    assert TABLE.read_text(encoding='utf-8') == parameters_markdown(), (
        f'docs/parameters.md is stale: regenerate it with `{REGENERATE}`'
    )


def test_the_params_command_prints_and_writes_the_table(tmp_path, capsys):
    assert main(['params']) == 0
    assert capsys.readouterr().out == parameters_markdown()
    out = tmp_path / 'parameters.md'
    assert main(['params', '--output', str(out)]) == 0
    assert out.read_text(encoding='utf-8') == parameters_markdown()


def test_every_end_of_every_range_is_refused_by_the_config_or_works():
    """Issue 26.1: a value the table allows either works or FusionConfig refuses it (an order
    between two parameters, such as range_min below range_max), never the stream later (the
    node applied it at run time and ended)."""
    from scanfuse.stream import FusionStream

    checked = 0
    for spec in params.fusion_param_specs(FusionConfig()):
        if spec.kind not in (Kind.INTEGER, Kind.DOUBLE) or spec.name == 'scan_row':
            continue
        bounds = spec.bounds
        for end, exclusive in (
            (bounds.low, bounds.low_exclusive),
            (bounds.high, bounds.high_exclusive),
        ):
            if end is None or exclusive:
                continue
            try:
                config = FusionConfig.from_dict({spec.name: end})
            except ConfigError as err:
                refusal = str(err)
                assert 'must be' in refusal, (spec.name, end, refusal)
                continue
            FusionStream(config)
            checked += 1
    assert checked > 40
