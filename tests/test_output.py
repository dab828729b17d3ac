"""Every source equal (issue 27): LiDARs only, camera only, clouds only, and the output in
any frame on any grid, against hand-worked geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.convert.row import row_scan
from scanfuse.errors import ConfigError
from scanfuse.frames import StampedTransform
from scanfuse.motion import PlanarPose
from scanfuse.output import grid_between
from scanfuse.stream import FusionStream, Passed
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.modes import (
    D2L_CAMERA,
    D2L_CX,
    D2L_CY,
    D2L_FX,
    LIDAR_AT,
    OMEGA,
    box_cloud,
    camera_only_params,
    clouds_only_params,
    d2l_images,
    lidar_in_world,
    lidars_only_params,
    turning_scan,
)
from tests.support.reference import d2l_scan_loop
from tests.support.render import box_depth, square_room_ranges
from tests.test_sources import HALF, NS, lidar_scan

FOV = math.radians(270.0)
FRONT = (0.3, 0.2), math.pi / 4  # front-left corner, facing front-left
REAR = (-0.3, -0.2), -3 * math.pi / 4  # rear-right corner, facing rear-right


def lidars_only(**changes) -> FusionConfig:
    """Two 270-degree LiDARs at opposite corners of the base, no camera, output in base_link
    over 360 degrees at half a degree (`modes.lidars_only_params`); a change to None drops
    the parameter."""
    values = {**lidars_only_params(), **changes}
    return FusionConfig.from_dict({k: v for k, v in values.items() if v is not None})


def covered_and_true(scan, origin=(0.0, 0.0), yaw=0.0) -> tuple[float, float]:
    """(share of slots with a finite reading, largest error of those against the room)."""
    truth = square_room_ranges(origin, yaw, scan.angles(), HALF)
    finite = np.isfinite(scan.ranges)
    error = float(np.max(np.abs(scan.ranges[finite] - truth[finite]))) if finite.any() else 0.0
    return float(finite.mean()), error


def test_two_corner_lidars_read_the_room_from_base_link_over_360_degrees():
    stream: FusionStream[int] = FusionStream(lidars_only())
    rear = lidar_scan(*REAR, 1080, FOV, 'rear')
    front = lidar_scan(*FRONT, 1080, FOV, 'front')
    assert stream.add_scan(rear, 0, NS, source='rear') == []
    (out,) = stream.add_scan(front, 1, NS + 1)
    assert out.fused is not None
    assert out.fused.frame_id == 'base_link'
    assert len(out.fused) == 720
    assert out.fused.angle_min == pytest.approx(-math.pi)
    assert out.fused.angle_increment == pytest.approx(math.pi / 360)
    assert out.fused.stamp_ns == front.stamp_ns
    covered, error = covered_and_true(out.fused)
    assert covered >= 0.95
    assert error <= 0.02
    # No camera is configured: nothing was passed over for want of one.
    assert out.passed is None
    assert stream.counts.passed == {}


def test_one_corner_lidar_in_base_link_is_true_where_it_sees_and_empty_behind_it():
    stream: FusionStream[int] = FusionStream(lidars_only())
    (out,) = stream.add_scan(lidar_scan(*FRONT, 1080, FOV, 'front'), 1, NS)
    assert out.fused is not None
    covered, error = covered_and_true(out.fused)
    assert error <= 0.02
    # From the corner it faces away from, a quarter of the room is out of its view.
    assert 0.6 < covered < 0.95


def test_output_frame_alone_keeps_the_lidars_grid():
    stream: FusionStream[int] = FusionStream(
        lidars_only(angle_increment=0.0, lidars=['front'], rear=None)
    )
    front = lidar_scan(*FRONT, 1080, FOV, 'front')
    (out,) = stream.add_scan(front, 1, NS)
    assert out.fused is not None
    assert out.fused.frame_id == 'base_link'
    assert out.fused.grid == front.grid
    # Its angles are base_link's now: the reading at bearing 0 is the wall at x = 2.
    assert out.fused.ranges[np.argmin(np.abs(front.angles()))] == pytest.approx(2.0, abs=0.02)


def test_an_output_frame_nothing_places_passes_the_lidar_and_says_which(caplog):
    stream: FusionStream[int] = FusionStream(lidars_only(output_frame='map'))
    (out,) = stream.add_scan(lidar_scan(*FRONT, 1080, FOV, 'front'), 1, NS)
    assert out.passed is Passed.FUSION_FAILED
    assert stream.counts.malformed == {'scan': 1}
    assert "output_frame 'map' is neither base_frame 'base_link'" in caplog.text


def test_no_source_at_all_is_a_config_error():
    with pytest.raises(ConfigError, match='no source: scan_topic and depth_topic are empty'):
        FusionConfig.from_dict({'scan_topic': '', 'depth_topic': ''})


def test_an_output_grid_needs_angle_max_above_angle_min():
    with pytest.raises(ConfigError, match=r'angle_max \(0.0\) must be above angle_min \(1.0\)'):
        FusionConfig.from_dict({'angle_increment': 0.01, 'angle_min': 1.0, 'angle_max': 0.0})


def test_a_full_turn_grid_holds_each_direction_once():
    grid = grid_between(-math.pi, math.pi, math.pi / 360)
    assert grid.count == 720
    assert grid_between(-1.0, 1.0, 0.5).count == 5


# ---------------------------------------------------------------- camera only


def camera_only(**changes) -> FusionConfig:
    return FusionConfig.from_dict({**camera_only_params(), **changes})


@pytest.mark.parametrize('case', list(d2l_images()))
def test_camera_only_row_d2l_is_depthimage_to_laserscan_bit_for_bit(case):
    depth = d2l_images()[case]
    stream: FusionStream[int] = FusionStream(camera_only())
    stream.add_camera_info(D2L_CAMERA)
    (out,) = stream.add_depth(NS, depth, NS, 'camera_depth_frame', token=7)
    assert out.token == 7
    assert out.fused is not None
    angle_min, angle_max, increment, ranges = d2l_scan_loop(
        depth, D2L_FX, D2L_CX, D2L_CY, scan_height=1, range_min=0.45, range_max=10.0
    )
    np.testing.assert_array_equal(out.fused.ranges, ranges)
    assert out.fused.angle_min == angle_min
    assert out.fused.angle_max == angle_max
    assert out.fused.angle_increment == increment
    assert out.fused.stamp_ns == NS
    assert out.fused.frame_id == 'camera_depth_frame'
    assert (out.fused.range_min, out.fused.range_max) == (0.45, 10.0)


def test_camera_only_output_frame_labels_the_row_scan_as_depthimage_to_laserscan_does():
    stream: FusionStream[int] = FusionStream(camera_only(output_frame='camera_link'))
    stream.add_camera_info(D2L_CAMERA)
    (out,) = stream.add_depth(NS, d2l_images()['fixture'], NS, 'camera_depth_frame', token=1)
    assert out.fused is not None
    assert out.fused.frame_id == 'camera_link'
    expected = row_scan(
        d2l_images()['fixture'], D2L_CAMERA, range_min=0.45, range_max=10.0, d2l_compat=True
    )
    np.testing.assert_array_equal(out.fused.ranges, expected.ranges)


def test_camera_only_obstacle_method_reports_a_box_from_base_link():
    # A camera 0.4 m up, 15 degrees down, looking along +x at a box whose face is 1.0 m
    # ahead: on the default grid from base_link the box reads 1.0 m ahead, the floor nothing.
    pitch = math.radians(15.0)
    config = FusionConfig.from_dict(
        {
            'scan_topic': '',
            'memory': False,
            'use_tf': False,
            'obstacle_min_points': 1,
            'camera_height': 0.4,
            'camera_pitch': pitch,
            'ground_estimate': False,
        }
    )
    camera = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')
    world_to_optical = Transform.from_rpy(0.0, pitch, 0.0, (0.0, 0.0, 0.4)) @ BODY_TO_OPTICAL
    metres = box_depth(camera, world_to_optical, [(1.0, 1.4, -0.2, 0.2, 0.0, 0.3)])
    stream: FusionStream[int] = FusionStream(config)
    stream.add_camera_info(camera)
    (out,) = stream.add_depth(NS, metres.astype(np.float32), NS, 'optical', token=1)
    assert out.fused is not None
    assert out.fused.frame_id == 'base_link'
    assert len(out.fused) == 720
    angles = out.fused.angles()
    ahead = np.abs(angles) < math.atan2(0.15, 1.0)
    np.testing.assert_allclose(out.fused.ranges[ahead], 1.0 / np.cos(angles[ahead]), atol=0.02)
    # Outside the box's bearings only floor is in view: nothing is reported.
    beside = (np.abs(angles) > math.atan2(0.25, 1.0)) & (np.abs(angles) < 0.6)
    assert not np.isfinite(out.fused.ranges[beside]).any()


def test_camera_only_memory_keeps_a_box_the_camera_turned_away_from():
    # The same box 1.0 m ahead; the robot then turns 90 degrees left on the spot (odometry
    # every 10 ms) and its camera sees only floor: the remembered box is on its right, its
    # face 1.0 m away at bearing -90 degrees (within the evaluation's 0.05 m + 2 %).
    pitch = math.radians(15.0)
    config = FusionConfig.from_dict(
        {
            'scan_topic': '',
            'use_tf': False,
            'camera_height': 0.4,
            'camera_pitch': pitch,
            'far_confirm_range': 0.0,  # the box shown from its first frame: test_far_confirm.py
        }
    )
    camera = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')
    stream: FusionStream[int] = FusionStream(config)
    stream.add_camera_info(camera)
    box = [(1.0, 1.4, -0.2, 0.2, 0.0, 0.3)]
    outputs = []
    for k in range(51):
        t_ns = NS + k * 10_000_000
        yaw = math.pi / 2 * k / 50
        stream.add_odometry(t_ns, PlanarPose(0.0, 0.0, yaw))
        if k in (0, 50):
            pose = Transform.from_rpy(0.0, pitch, yaw, (0.0, 0.0, 0.4)) @ BODY_TO_OPTICAL
            depth = box_depth(camera, pose, box).astype(np.float32)
            outputs += stream.add_depth(t_ns, depth, t_ns, 'optical', token=k)
    first, turned = outputs
    assert first.fused is not None
    assert turned.fused is not None
    assert turned.depth_scan is not None
    angles = turned.fused.angles()
    right = np.abs(angles + math.pi / 2) < math.atan2(0.15, 1.0)
    assert not np.isfinite(turned.depth_scan.ranges[right]).any()  # not in view now
    truth = 1.0 / np.cos(angles[right] + math.pi / 2)
    np.testing.assert_allclose(turned.fused.ranges[right], truth, atol=0.05 + 0.02 * 1.0)


def test_a_camera_tf_cannot_place_makes_no_output_and_says_why(caplog):
    # TF knows the camera's frame, under another root than base_link: the mounting would be
    # a guess, so the frame makes no output (counted), as a scan would pass through.
    stream: FusionStream[int] = FusionStream(camera_only(use_tf=True))
    stream.add_camera_info(D2L_CAMERA)
    stream.add_transforms(
        [StampedTransform('camera_link', 'camera_depth_frame', (0.0, 0.0, 0.0), (0, 0, 0, 1))],
        static=True,
    )
    depth = d2l_images()['fixture']
    assert stream.add_depth(NS, depth, NS, 'camera_depth_frame', token=1) == []
    assert stream.counts.passed == {Passed.FUSION_FAILED: 1}
    expected = 'TF does not relate base_frame base_link to the camera frame camera_depth_frame'
    assert expected in caplog.text


# ---------------------------------------------------------------- clouds only


def test_clouds_only_report_the_slab_box_and_not_the_floor():
    points = box_cloud()
    stream: FusionStream[int] = FusionStream(FusionConfig.from_dict(clouds_only_params()))
    (out,) = stream.add_cloud(NS, points, NS, 'points', 'points', token=3)
    assert out.token == 3
    assert out.fused is not None
    assert out.fused.frame_id == 'base_link'
    assert out.fused.stamp_ns == NS
    angles = out.fused.angles()
    ahead = np.abs(angles) < math.atan2(0.18, 1.5)
    np.testing.assert_allclose(out.fused.ranges[ahead], 1.5 / np.cos(angles[ahead]), atol=0.03)
    # Everywhere else only floor: nothing.
    assert not np.isfinite(out.fused.ranges[np.abs(angles) > math.atan2(0.25, 1.5)]).any()


# ---------------------------------------------------------------- fixed rate


def turning_robot(publish_rate: float, **changes):
    """A robot turning at OMEGA with a 360-degree LiDAR (0.25 degrees, no de-skew needed:
    time_increment 0) at 10 Hz, odometry at 100 Hz; outputs at `publish_rate`."""
    config = FusionConfig.from_dict(
        {
            'use_tf': False,
            'memory': False,
            'depth_topic': '',
            'publish_rate': publish_rate,
            'lidar_x': LIDAR_AT[0],
            'lidar_y': LIDAR_AT[1],
            **changes,
        }
    )
    return FusionStream(config)


def run_turning(stream, seconds: float, *, scans_until: float | None = None):
    """Odometry every 10 ms and a scan every 100 ms (until `scans_until`), in stamp order."""
    outputs = []
    for k in range(round(seconds * 100) + 1):
        t_ns = NS + k * 10_000_000
        stream.add_odometry(t_ns, PlanarPose(0.0, 0.0, OMEGA * t_ns / 1e9))
        if k % 10 == 0 and (scans_until is None or k / 100 <= scans_until):
            outputs += stream.add_scan(turning_scan(t_ns), k, t_ns)
        else:
            outputs += stream.tick(t_ns)
    return outputs + stream.finish()


def test_a_fixed_rate_moves_a_10_hz_lidar_to_20_hz_stamps_while_turning_at_1_rad_s():
    outputs = run_turning(turning_robot(20.0), 1.0)
    stamps = [out.fused.stamp_ns for out in outputs]
    assert stamps == [NS + k * 50_000_000 for k in range(21)]
    for out in outputs:
        origin, yaw = lidar_in_world(out.fused.stamp_ns / 1e9)
        truth = square_room_ranges(origin, yaw, out.fused.angles(), HALF)
        finite = np.isfinite(out.fused.ranges)
        assert finite.mean() >= 0.95
        np.testing.assert_allclose(out.fused.ranges[finite], truth[finite], atol=0.02)
    # Between scans (every other output) the scan 50 ms old is moved: without the move a
    # 0.05 rad turn would put the walls off by far more than 2 cm.
    unmoved = turning_scan(NS).ranges
    origin, yaw = lidar_in_world(0.05)
    truth = square_room_ranges(origin, yaw, outputs[1].fused.angles(), HALF)
    assert np.nanmax(np.abs(unmoved - truth)) > 0.1


def test_a_fixed_rate_does_not_move_a_scan_older_than_its_max_time_offset():
    # Scans stop after 0.3 s; odometry goes on: outputs go on only while the last scan is
    # at most max_time_offset (0.1 s) old.
    outputs = run_turning(turning_robot(20.0), 1.0, scans_until=0.3)
    stamps = [out.fused.stamp_ns for out in outputs]
    assert stamps == [NS + k * 50_000_000 for k in range(9)]  # up to 0.4 s


def test_a_fixed_rate_needs_a_lidar():
    with pytest.raises(ConfigError, match='publish_rate moves LiDAR scans to its stamps'):
        FusionConfig.from_dict({'scan_topic': '', 'publish_rate': 20.0})


# ---------------------------------------------------------------- trigger


def test_trigger_names_the_lidar_whose_scans_make_the_outputs():
    config = lidars_only(trigger='rear', output_frame='', angle_increment=0.0)
    assert [s.name for s in config.sources.lidars] == ['rear', 'front']
    assert config.scan_topic == '/rear/scan'  # the one-source parameters follow it
    assert config.with_changes(memory=False).sources == config.sources
    stream: FusionStream[int] = FusionStream(config)
    front = lidar_scan(*FRONT, 1080, FOV, 'front', stamp=NS - 20_000_000)
    rear = lidar_scan(*REAR, 1080, FOV, 'rear')
    assert stream.add_scan(front, 0, NS, source='front') == []  # no output of its own
    (out,) = stream.add_scan(rear, 1, NS + 1, source='rear')
    assert out.fused is not None
    assert (out.fused.frame_id, out.fused.stamp_ns) == ('rear', rear.stamp_ns)
    # The rear LiDAR's frame, filled by the front one: the room from the rear corner.
    covered, error = covered_and_true(out.fused, *REAR)
    assert error <= 0.02
    assert covered == 1.0


def test_a_trigger_that_is_no_source_or_cannot_trigger_is_refused():
    with pytest.raises(ConfigError, match=r"trigger 'side' is no named source \(named: front"):
        lidars_only(trigger='side')
    cameras = {
        'cameras': ['depth'],
        'depth': {'depth_topic': '/d', 'camera_info_topic': '/i'},
        'trigger': 'depth',
    }
    with pytest.raises(ConfigError, match=r"trigger 'depth' is a camera: .* without a LiDAR"):
        FusionConfig.from_dict(cameras)
    assert FusionConfig.from_dict({**cameras, 'scan_topic': ''}).trigger == 'depth'


# ------------------------------------------------------------------ limits and no return


def open_field_scan(origin, yaw, *, free_from: float = -math.pi):
    """`lidar_scan` of the front LiDAR with no return (+Inf) at every beam whose own angle
    is above `free_from` (-pi: every beam), the room's walls at the others."""
    scan = lidar_scan(origin, yaw, 1080, FOV, 'front')
    ranges = np.where(scan.angles() > free_from, np.inf, scan.ranges).astype(np.float32)
    return scan.with_ranges(ranges)


def bearing_between(scan, low: float, high: float) -> np.ndarray:
    angles = scan.angles()
    return (angles > low) & (angles < high)


def test_a_lidars_no_return_stays_no_return_in_base_link():
    # The front LiDAR faces pi/4 and sees 270 degrees: far away, where its origin's offset
    # no longer matters, it looks along base_link bearings from -pi/2 to pi; behind its back
    # (bearings -pi to -pi/2) it says nothing. No return (+Inf) must stay +Inf there (REP-117:
    # free as far as it sees), not become NaN (no measurement), and NaN behind it.
    stream: FusionStream[int] = FusionStream(lidars_only())
    (out,) = stream.add_scan(open_field_scan(*FRONT), 1, NS)
    assert out.fused is not None
    margin = math.radians(1.0)
    seen = bearing_between(out.fused, -math.pi / 2 + margin, math.pi - margin)
    behind = bearing_between(out.fused, -math.pi + margin, -math.pi / 2 - margin)
    assert np.isposinf(out.fused.ranges[seen]).all()
    assert np.isnan(out.fused.ranges[behind]).all()


def test_no_return_beside_walls_keeps_the_walls_true():
    # Beams at the LiDAR's own angles above 0 (base_link bearings above pi/4) return
    # nothing; the others see the room. The walls stay within 2 cm of the room's truth from
    # base_link; well inside the free sector (20 degrees from its edge: a wall point seen
    # from the corner lies up to atan(0.36 / 1.5) = 14 degrees off its bearing from the
    # LiDAR) every slot is +Inf.
    stream: FusionStream[int] = FusionStream(lidars_only())
    (out,) = stream.add_scan(open_field_scan(*FRONT, free_from=0.0), 1, NS)
    assert out.fused is not None
    _, error = covered_and_true(out.fused)
    assert error <= 0.02
    margin = math.radians(20.0)
    free = bearing_between(out.fused, math.pi / 4 + margin, math.pi - margin)
    assert np.isposinf(out.fused.ranges[free]).all()
    walls = bearing_between(out.fused, -math.pi / 2 + margin, math.pi / 4 - margin)
    assert np.isfinite(out.fused.ranges[walls]).all()


def test_output_range_limits_drop_the_near_and_free_the_far():
    # The room from base_link reads 2.0 m (axes) to 2.83 m (corners). With output limits
    # 2.1 .. 2.3 m: a wall nearer than 2.1 m is dropped (NaN), one farther than 2.3 m is no
    # return within range (+Inf), those between stay true; the scan says 2.1 .. 2.3.
    stream: FusionStream[int] = FusionStream(
        lidars_only(output_range_min=2.1, output_range_max=2.3)
    )
    rear = lidar_scan(*REAR, 1080, FOV, 'rear')
    stream.add_scan(rear, 0, NS, source='rear')
    (out,) = stream.add_scan(lidar_scan(*FRONT, 1080, FOV, 'front'), 1, NS + 1)
    assert out.fused is not None
    assert (out.fused.range_min, out.fused.range_max) == (2.1, 2.3)
    truth = square_room_ranges((0.0, 0.0), 0.0, out.fused.angles(), HALF)
    ranges = out.fused.ranges
    covered = ~np.isnan(lidar_scan_union(rear))
    near, far = truth < 2.05, truth > 2.35
    between = (truth > 2.15) & (truth < 2.25)
    assert near.any()
    assert far.any()
    assert between.any()
    assert np.isnan(ranges[near]).all()
    assert np.isposinf(ranges[far & covered]).all()
    np.testing.assert_allclose(ranges[between & covered], truth[between & covered], atol=0.02)


def lidar_scan_union(rear) -> np.ndarray:
    """Slots either LiDAR reads a wall in, without output limits (the same two scans)."""
    free: FusionStream[int] = FusionStream(lidars_only())
    free.add_scan(rear, 0, NS, source='rear')
    (out,) = free.add_scan(lidar_scan(*FRONT, 1080, FOV, 'front'), 1, NS + 1)
    assert out.fused is not None
    return out.fused.ranges


def test_output_range_max_not_above_output_range_min_is_refused():
    refused = r'output_range_max \(1.0\) must be above output_range_min'
    with pytest.raises(ConfigError, match=refused):
        lidars_only(output_range_min=2.0, output_range_max=1.0)
