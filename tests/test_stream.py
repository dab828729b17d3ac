"""`FusionStream`: pairing, pass-through, motion compensation, de-skew and bad input.

Geometry is worked out by hand: a robot turning in place at OMEGA rad/s with the camera
and the LiDAR at its centre sees a post; between the camera's stamp and the scan's the
robot turns by OMEGA * dt, so an uncompensated depth frame puts the post that far off.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.errors import InputError
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.stream import Compensation, FusionStream, Passed
from tests.support.render import Box, camera_in_world, depth_image, turning_sweep

NS = 1_000_000_000
OMEGA = 1.5  # rad/s, turning left
CAMERA_HEIGHT, PITCH = 0.4, math.radians(15.0)
POST = Box(1.5, 1.6, -0.05, 0.05, 0.2)  # front face 1.5 m ahead at yaw 0, below the LiDAR plane
T_SCAN = 100 * NS
READINGS = 3600  # 0.1 degree slots
CAMERA = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')


def config(**changes) -> FusionConfig:
    values = {
        'use_tf': False,
        'camera_height': CAMERA_HEIGHT,
        'camera_pitch': PITCH,
        'lidar_height': 0.3,
        'range_max': 3.0,
        'obstacle_min_points': 1,
        'memory': False,  # the memory has its own tests (test_memory.py)
        'far_confirm_range': 0.0,  # and far readings' confirmation (test_far_confirm.py)
        **changes,
    }
    return FusionConfig(**values)


def lidar_scan(stamp_ns: int, ranges=None, *, time_increment: float = 0.0) -> Scan:
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - 2 * math.pi / READINGS,
        angle_increment=2 * math.pi / READINGS,
        range_min=0.05,
        range_max=10.0,
        ranges=np.full(READINGS, np.inf, dtype=np.float32) if ranges is None else ranges,
        time_increment=time_increment,
        frame_id='laser',
        stamp_ns=stamp_ns,
    )


def yaw_at(stamp_ns: int) -> float:
    return OMEGA * (stamp_ns - T_SCAN) / NS  # yaw 0 at the scan's stamp


def feed_turning_odometry(stream: FusionStream, until_ns: int) -> None:
    for stamp in range(T_SCAN - NS // 2, until_ns + 1, NS // 50):  # 50 Hz
        stream.add_odometry(stamp, PlanarPose(0.0, 0.0, yaw_at(stamp)))


def post_bearing_and_range(scan: Scan) -> tuple[float, float]:
    """Mean bearing (degrees) of the slots that see the post, and its nearest range."""
    near = np.isfinite(scan.ranges) & (scan.ranges < 2.0)
    assert near.any(), 'the post is not in the scan'
    angles = scan.angles()[near]
    bearing = math.degrees(math.atan2(np.sin(angles).mean(), np.cos(angles).mean()))
    return bearing, float(scan.ranges[near].min())


def depth_seen_at(stamp_ns: int) -> np.ndarray:
    pose = camera_in_world(0.0, 0.0, yaw_at(stamp_ns), height=CAMERA_HEIGHT, pitch=PITCH)
    return depth_image(CAMERA, pose, [POST])


def fused_post(stream: FusionStream, camera_ns: int) -> tuple[float, float, Compensation]:
    stream.add_camera_info(CAMERA)
    stream.add_depth(camera_ns, depth_seen_at(camera_ns), camera_ns + 40_000_000)
    (out,) = stream.add_scan(lidar_scan(T_SCAN), 'scan', T_SCAN + 10_000_000)
    assert out.fused is not None, out.passed
    return (*post_bearing_and_range(out.fused), out.compensation)


def test_a_turning_robot_sees_the_post_where_it_is_at_the_scan_stamp():
    camera_ns = T_SCAN - 50_000_000  # the depth frame is 50 ms older than the scan
    stream: FusionStream[str] = FusionStream(config())
    feed_turning_odometry(stream, T_SCAN + 20_000_000)
    bearing, distance, compensation = fused_post(stream, camera_ns)
    assert compensation is Compensation.COMPENSATED
    # At the scan's stamp the robot faces the post: bearing 0, front face 1.5 m away.
    assert bearing == pytest.approx(0.0, abs=0.2)
    assert distance == pytest.approx(1.5, abs=0.01)


def test_without_compensation_the_post_is_off_by_the_turn_since_the_camera_stamp():
    camera_ns = T_SCAN - 50_000_000
    stream: FusionStream[str] = FusionStream(config(motion_compensation=False))
    feed_turning_odometry(stream, T_SCAN + 20_000_000)
    bearing, distance, compensation = fused_post(stream, camera_ns)
    assert compensation is Compensation.OFF
    # 50 ms at 1.5 rad/s: the frame was taken 4.3 degrees of turn earlier, post to the left.
    assert bearing == pytest.approx(math.degrees(OMEGA * 0.05), abs=0.2)
    assert distance == pytest.approx(1.5, abs=0.01)


def test_without_odometry_the_stream_fuses_as_if_standing_and_says_so_once(caplog):
    stream: FusionStream[str] = FusionStream(config())
    stream.add_camera_info(CAMERA)
    with caplog.at_level(logging.DEBUG, logger='scanfuse.stream'):
        for index in range(3):
            stamp = T_SCAN + index * NS // 10
            stream.add_depth(stamp - 20_000_000, depth_seen_at(T_SCAN), stamp)
            (out,) = stream.add_scan(lidar_scan(stamp), index, stamp + 1)
            assert out.compensation is Compensation.NO_ODOMETRY
            assert out.fused is not None
    assert caplog.text.count('fusing without motion compensation') == 1


def test_lidar_deskew_puts_a_late_beam_where_the_post_is_at_the_stamp():
    sweep = 0.1
    centre_bearing = 2.0  # radians; its beams come about 0.08 s into the sweep
    centre = (1.5 * math.cos(centre_bearing), 1.5 * math.sin(centre_bearing))
    ranges, angle_min, increment = turning_sweep(
        READINGS, sweep, OMEGA, centre, 0.05, range_max=10.0
    )
    raw = lidar_scan(T_SCAN, ranges, time_increment=sweep / READINGS)
    assert raw.angle_min == angle_min
    assert raw.angle_increment == pytest.approx(increment)
    raw_bearing, _ = post_bearing_and_range(raw)
    # Skewed: the beams saw the post while the sensor had turned by OMEGA * t_beam.
    assert math.radians(raw_bearing) == pytest.approx(
        centre_bearing - OMEGA * sweep * (centre_bearing + math.pi) / (2 * math.pi), abs=0.005
    )
    stream: FusionStream[str] = FusionStream(config())
    feed_turning_odometry(stream, T_SCAN + 150_000_000)
    (out,) = stream.add_scan(raw, 'scan', T_SCAN + 110_000_000)
    assert out.passed is Passed.NO_CAMERA_INFO
    assert out.deskewed
    assert out.fused is not None  # the de-skewed LiDAR scan is what leaves
    bearing, distance = post_bearing_and_range(out.fused)
    assert bearing == pytest.approx(math.degrees(centre_bearing), abs=0.2)
    assert distance == pytest.approx(1.45, abs=0.01)  # centre 1.5 m, radius 0.05 m


def test_deskew_off_or_without_time_increment_keeps_the_scan():
    stream: FusionStream[str] = FusionStream(config(deskew=False))
    feed_turning_odometry(stream, T_SCAN + 150_000_000)
    scan = lidar_scan(T_SCAN, time_increment=0.1 / READINGS)
    (out,) = stream.add_scan(scan, 'a', T_SCAN + 110_000_000)
    assert not out.deskewed
    assert out.fused is None  # unchanged: the adapter sends the LiDAR's own bytes
    stream = FusionStream(config())
    feed_turning_odometry(stream, T_SCAN + 150_000_000)
    (out,) = stream.add_scan(lidar_scan(T_SCAN), 'b', T_SCAN + 110_000_000)
    assert not out.deskewed


# ------------------------------------------------------------------ pairing


def flat_depth() -> np.ndarray:
    return np.full((CAMERA.height, CAMERA.width), 2000, dtype=np.uint16)


def standing(**changes) -> FusionStream[int]:
    stream: FusionStream[int] = FusionStream(config(**changes))
    stream.add_camera_info(CAMERA)
    return stream


def test_a_scan_pairs_with_the_nearest_frame_within_max_time_offset():
    stream = standing(max_time_offset=0.1)
    for stamp in (0.90, 0.96, 1.08):
        stream.add_depth(round(stamp * NS), flat_depth(), round(stamp * NS))
    (out,) = stream.add_scan(lidar_scan(NS), 1, NS + 1)
    assert out.depth_stamp_ns == round(0.96 * NS)  # 40 ms before, nearer than 80 ms after


def test_of_two_equally_near_frames_the_earlier_wins():
    stream = standing()
    stream.add_depth(NS - 50_000_000, flat_depth(), NS)
    stream.add_depth(NS + 50_000_000, flat_depth(), NS + 1)
    (out,) = stream.add_scan(lidar_scan(NS), 1, NS + 2)
    assert out.depth_stamp_ns == NS - 50_000_000


def test_a_scan_older_than_every_frame_by_more_than_the_offset_passes_through():
    stream = standing(max_time_offset=0.1)
    stream.add_depth(2 * NS, flat_depth(), 2 * NS)
    (out,) = stream.add_scan(lidar_scan(NS), 7, 2 * NS + 1)
    assert (out.token, out.passed, out.fused) == (7, Passed.NO_FRAME_NEAR, None)
    assert stream.counts.passed == {Passed.NO_FRAME_NEAR: 1}


def test_a_depth_frame_from_the_future_pairs_only_with_scans_near_it():
    stream = standing(max_time_offset=0.1)
    stream.add_depth(NS, flat_depth(), NS)
    stream.add_depth(60 * NS, flat_depth(), NS + 10)  # a clock jump on the camera
    outs = [stream.add_scan(lidar_scan(NS + k * NS // 10), k, NS + 20 + k)[0] for k in range(3)]
    assert [o.token for o in outs] == [0, 1, 2]
    assert outs[0].depth_stamp_ns == NS
    assert [o.passed for o in outs[1:]] == [None, Passed.NO_FRAME_NEAR]
    assert outs[1].depth_stamp_ns == NS  # 0.1 s away: within the offset


def test_pair_wait_holds_a_scan_until_a_later_frame_and_keeps_the_order():
    stream = standing()
    stream = FusionStream(config(), pair_wait=0.05)
    stream.add_camera_info(CAMERA)
    stream.add_depth(NS - 30_000_000, flat_depth(), NS - 1)
    assert stream.add_scan(lidar_scan(NS), 1, NS) == []  # waits for a frame after it
    assert stream.add_scan(lidar_scan(NS + 10_000_000), 2, NS + 5_000_000) == []
    assert stream.next_deadline_ns() == NS + 50_000_000
    released = stream.add_depth(NS + 20_000_000, flat_depth(), NS + 30_000_000)
    assert [o.token for o in released] == [1, 2]
    assert [o.depth_stamp_ns for o in released] == [NS + 20_000_000] * 2  # 20 ms < 30 ms


def test_pair_wait_ends_at_the_deadline():
    stream = FusionStream(config(), pair_wait=0.05)
    stream.add_camera_info(CAMERA)
    stream.add_depth(NS - 30_000_000, flat_depth(), NS - 1)
    assert stream.add_scan(lidar_scan(NS), 1, NS) == []
    assert stream.tick(NS + 49_000_000) == []
    (out,) = stream.tick(NS + 50_000_000)
    assert out.depth_stamp_ns == NS - 30_000_000


def test_a_silent_camera_releases_waiting_scans_at_once_and_passes_them():
    stream = FusionStream(config(camera_timeout=0.3), pair_wait=1.0)
    stream.add_camera_info(CAMERA)
    stream.add_depth(0, flat_depth(), 0)
    (out,) = stream.add_scan(lidar_scan(NS), 1, NS)  # the camera has been silent 1 s
    assert out.passed is Passed.CAMERA_SILENT


def test_no_camera_info_passes_through_without_waiting():
    stream: FusionStream[int] = FusionStream(config(), pair_wait=1.0)
    (out,) = stream.add_scan(lidar_scan(NS), 1, NS)
    assert out.passed is Passed.NO_CAMERA_INFO


def test_stamps_going_backwards_are_fused_in_arrival_order_and_warned_once(caplog):
    stream = standing()
    stamps = [NS, 2 * NS, int(1.5 * NS), int(1.2 * NS)]
    with caplog.at_level(logging.WARNING, logger='scanfuse.stream'):
        outs = []
        for index, stamp in enumerate(stamps):
            stream.add_depth(stamp - 10_000_000, flat_depth(), 3 * NS + index)
            outs += stream.add_scan(lidar_scan(stamp), index, 3 * NS + index)
    assert [o.token for o in outs] == [0, 1, 2, 3]
    assert [o.depth_stamp_ns for o in outs] == [s - 10_000_000 for s in stamps]
    assert caplog.text.count('stamps went backwards') == 1


def test_an_odometry_gap_between_the_stamps_passes_the_scan_through_counted(caplog):
    stream = standing()
    stream.add_odometry(0, PlanarPose(0.0, 0.0, 0.0))
    stream.add_odometry(20_000_000, PlanarPose(0.0, 0.0, 0.0))
    stream.add_odometry(NS, PlanarPose(0.0, 0.0, 0.0))  # 0.98 s without odometry: a break
    stream.add_odometry(NS + 20_000_000, PlanarPose(0.0, 0.0, 0.0))
    with caplog.at_level(logging.WARNING, logger='scanfuse.stream'):
        stream.add_depth(NS - 50_000_000, flat_depth(), NS)
        (out,) = stream.add_scan(lidar_scan(NS + 10_000_000), 1, NS + 15_000_000)
    assert out.passed is Passed.NO_MOTION
    assert out.fused is None
    assert 'odometry jump or gap' in caplog.text
    assert stream.counts.passed == {Passed.NO_MOTION: 1}


def test_an_odometry_jump_breaks_compensation_across_it_but_not_after_it():
    stream = standing()
    for k in range(10):
        stream.add_odometry(k * 20_000_000, PlanarPose(0.0, 0.0, 0.0))
    for k in range(10, 20):  # a reset: 5 m away within 20 ms
        stream.add_odometry(k * 20_000_000, PlanarPose(5.0, 0.0, 0.0))
    stream.add_depth(150_000_000, flat_depth(), 160_000_000)
    (across,) = stream.add_scan(lidar_scan(210_000_000), 1, 215_000_000)
    assert across.passed is Passed.NO_MOTION
    stream.add_depth(280_000_000, flat_depth(), 290_000_000)
    (after,) = stream.add_scan(lidar_scan(300_000_000), 2, 305_000_000)
    assert after.passed is None
    assert after.compensation is Compensation.COMPENSATED


def test_odometry_too_far_behind_the_scan_passes_it_through():
    stream = standing(max_odometry_extrapolation=0.05)
    for k in range(10):
        stream.add_odometry(k * 20_000_000, PlanarPose(0.0, 0.0, 0.0))  # up to 0.18 s
    stream.add_depth(150_000_000, flat_depth(), 160_000_000)
    (near,) = stream.add_scan(lidar_scan(200_000_000), 1, 205_000_000)  # 20 ms ahead: ok
    assert near.compensation is Compensation.COMPENSATED
    stream.add_depth(280_000_000, flat_depth(), 285_000_000)
    (far,) = stream.add_scan(lidar_scan(300_000_000), 2, 305_000_000)  # 120 ms ahead
    assert far.passed is Passed.NO_MOTION


def test_nan_odometry_is_rejected_and_counted():
    stream = standing()
    stream.add_odometry(0, PlanarPose(0.0, 0.0, 0.0))
    stream.add_odometry(20_000_000, PlanarPose(math.nan, 0.0, 0.0))
    assert len(stream.odometry) == 1
    assert stream.odometry.rejected == 1


def test_a_scan_with_no_readings_is_refused_and_the_stream_goes_on():
    stream = standing()
    empty = Scan(-math.pi, -math.pi, 1.0, 0.05, 10.0, np.array([], np.float32), stamp_ns=NS)
    with pytest.raises(InputError, match=r'LiDAR scan on /scan has no readings.*skipped'):
        stream.add_scan(empty, 1, NS)
    stream.add_depth(NS, flat_depth(), NS)
    (out,) = stream.add_scan(lidar_scan(NS + 1), 2, NS + 2) + stream.finish()
    assert (out.token, out.fused is not None) == (2, True)
    assert stream.counts.scans == 1


def test_negative_pair_wait_is_an_error():
    with pytest.raises(InputError, match='pair_wait must be >= 0'):
        FusionStream(config(), pair_wait=-1.0)


def test_a_tf_loop_is_a_malformed_transform_and_no_scan_is_lost():
    from scanfuse.frames import StampedTransform

    stream = standing(use_tf=True)
    stream.add_transforms(
        [StampedTransform('laser', 'odom', (0, 0, 0), (0, 0, 0, 1))], static=False
    )
    stream.add_transforms(
        [StampedTransform('odom', 'laser', (0, 0, 0), (0, 0, 0, 1))], static=False
    )
    assert stream.counts.malformed == {'tf': 1}
    stream.add_depth(NS, flat_depth(), NS)
    outs = stream.add_scan(lidar_scan(NS), 1, NS + 1) + stream.finish()
    assert [o.token for o in outs] == [1]


def test_the_extrinsics_reported_follow_tf_that_arrives_after_the_first_choice():
    # The node chooses extrinsics when CameraInfo arrives; /tf_static may come later. What
    # it reports must then name the TF it has, not "TF has neither sensor frame".
    from scanfuse.ros.messages import transforms_from_cdr
    from tests.support.synthetic import Scene, scene_messages

    (tf_static,) = [raw for topic, _, _, raw in scene_messages(Scene()) if topic == '/tf_static']
    stream: FusionStream[int] = FusionStream(FusionConfig())
    stream.extrinsics_for('laser', 'camera_depth_optical_frame')
    assert stream.extrinsics_source == (
        'parameters (TF has neither sensor frame: '
        'no laser or camera_depth_optical_frame on /tf_static or /tf yet)'
    )
    stream.add_transforms(transforms_from_cdr(tf_static), static=True)
    assert stream.extrinsics_source == 'TF (base_link -> laser, camera_depth_optical_frame)'


def test_on_output_receives_every_scan_whichever_call_released_it():
    # The README's case: pair_wait 0.05 s and each frame 40 ms after its scan. add_scan
    # returns nothing (the scan waits for a later frame); add_depth and finish release them.
    received: list = []
    stream: FusionStream[int] = FusionStream(config(), pair_wait=0.05, on_output=received.append)
    stream.add_camera_info(CAMERA)
    returned = []
    ms = 1_000_000
    for step in range(4):
        stamp = T_SCAN + step * 100 * ms
        returned += stream.add_scan(lidar_scan(stamp), step, stamp)
        returned += stream.add_depth(stamp + 20 * ms, depth_seen_at(T_SCAN), stamp + 40 * ms)
    returned += stream.finish()
    assert [output.token for output in received] == [0, 1, 2, 3]
    # What the calls returned is the same outputs, in the same order.
    assert [output.token for output in returned] == [0, 1, 2, 3]
    assert all(a is b for a, b in zip(received, returned, strict=True))
