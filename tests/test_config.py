"""FusionConfig and ROS 2 parameter files."""

from __future__ import annotations

import math

import pytest
import yaml

from scanfuse import ConfigError, FusionConfig, Method, Resampler
from tests.support import REPOSITORY


def write(tmp_path, text):
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    return path


def test_defaults_fit_a_d435_above_a_2d_lidar():
    config = FusionConfig()
    assert config.method is Method.OBSTACLE
    assert config.resample is Resampler.CONSERVATIVE
    assert (config.range_min, config.range_max) == (0.2, 3.0)
    assert config.camera_pitch == pytest.approx(math.radians(20))


def test_loads_the_node_section_of_a_ros2_parameter_file(tmp_path):
    path = write(
        tmp_path,
        'scanfuse:\n  ros__parameters:\n    method: row\n    resample: linear\n'
        '    scan_height: 5\n    camera_height: 0.3\n',
    )
    config = FusionConfig.from_ros_params(path)
    assert config.method is Method.ROW
    assert config.resample is Resampler.LINEAR
    assert config.scan_height == 5
    assert config.camera_height == 0.3


def test_wildcard_section_is_accepted(tmp_path):
    path = write(tmp_path, '/**:\n  ros__parameters:\n    range_max: 4.0\n')
    assert FusionConfig.from_ros_params(path).range_max == 4.0


def test_round_trip_through_the_parameter_file_form(tmp_path):
    config = FusionConfig(method=Method.ROW, scan_row=100, camera_yaw=0.5)
    path = write(tmp_path, yaml.safe_dump(config.to_ros_params()))
    assert FusionConfig.from_ros_params(path) == config


def test_unknown_parameter_is_named(tmp_path):
    path = write(tmp_path, 'scanfuse:\n  ros__parameters:\n    scan_hieght: 3\n')
    with pytest.raises(ConfigError, match='scan_hieght: Extra inputs are not permitted'):
        FusionConfig.from_ros_params(path)


def test_bad_method_is_named():
    with pytest.raises(ConfigError, match="method: Input should be 'row' or 'obstacle'"):
        FusionConfig.from_dict({'method': 'pointcloud'})


def test_inverted_limits_are_rejected():
    with pytest.raises(ConfigError, match=r'range_min \(5.0\) must be smaller than range_max'):
        FusionConfig.from_dict({'range_min': 5.0, 'range_max': 1.0})
    with pytest.raises(ConfigError, match=r'min_obstacle_height .* must be below'):
        FusionConfig.from_dict({'min_obstacle_height': 0.6, 'max_obstacle_height': 0.5})


def test_missing_section_lists_what_the_file_has(tmp_path):
    path = write(tmp_path, 'other_node:\n  ros__parameters: {}\n')
    with pytest.raises(
        ConfigError, match=r'no "scanfuse: ros__parameters:" section \(found: other_node\)'
    ):
        FusionConfig.from_ros_params(path)


def test_missing_file_and_bad_yaml_are_clear(tmp_path):
    with pytest.raises(ConfigError, match='cannot read parameter file'):
        FusionConfig.from_ros_params(tmp_path / 'nope.yaml')
    with pytest.raises(ConfigError, match='not valid YAML'):
        FusionConfig.from_ros_params(write(tmp_path, 'scanfuse: [unclosed'))


def test_with_changes_validates():
    config = FusionConfig().with_changes(scan_height=3)
    assert config.scan_height == 3
    with pytest.raises(ConfigError, match='scan_height'):
        FusionConfig().with_changes(scan_height=0)


def test_shipped_example_parameter_file_holds_every_parameter():

    path = REPOSITORY / 'examples' / 'scanfuse.yaml'
    params = yaml.safe_load(path.read_text())['scanfuse']['ros__parameters']
    assert set(params) == set(FusionConfig.model_fields) - {'scan_row', 'sources'}
    FusionConfig.from_ros_params(path)


def test_d2l_compat_refuses_an_off_centre_row():
    with pytest.raises(ConfigError, match='leave scan_row unset or turn d2l_compat off'):
        FusionConfig.from_dict({'d2l_compat': True, 'scan_row': 10})


def test_the_robot_parameter_file_with_node_settings_loads_for_bag_and_simulator():
    from scanfuse.config import NODE_ONLY
    from scanfuse.ros.params import NodeSettings
    from tests.support import REPOSITORY

    assert set(NodeSettings.model_fields) == NODE_ONLY
    config = FusionConfig.from_ros_params(REPOSITORY / 'examples' / 'scanfuse_robot.yaml')
    assert config.depth_topic == '/camera/camera/depth/image_rect_raw'
