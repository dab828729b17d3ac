"""The node's mount check (issue 25): /diagnostics WARNs, with both numbers, when the floor
it finds disagrees with the camera's mounting over many frames; and its IMU input.

Driven through `LiveFusion` (the node's adapter) with CDR messages, as the node gets them.
"""

from __future__ import annotations

import math

import pytest

from scanfuse.convert.ground import MOUNT_CHECK_FRAMES
from scanfuse.ros.live import Level, LiveFusion, State
from scanfuse.ros.messages import (
    ImuOrientation,
    camera_to_cdr,
    depth_to_cdr,
    imu_to_cdr,
    scan_from_cdr,
    scan_to_cdr,
)
from scanfuse.transforms import Transform
from tests.support.ground_scene import (
    BOX,
    CAMERA,
    HEIGHT,
    NS,
    PITCH,
    config,
    lidar_scan,
    optical_pose,
    score,
)
from tests.support.render import box_depth, millimetres


def run(live: LiveFusion, depth, frames: int, *, imu=None) -> list:
    outputs = []
    live.on_camera_info(camera_to_cdr(CAMERA, stamp_ns=0), 0.0)
    for index in range(1, frames + 1):
        stamp = index * NS // 10
        now = stamp / NS
        if imu is not None:
            live.on_imu(imu_to_cdr(ImuOrientation(stamp, 'base_link', imu)))
        outputs += live.on_depth(depth_to_cdr(depth, frame_id='optical', stamp_ns=stamp), now)
        outputs += live.on_scan(scan_to_cdr(lidar_scan(stamp)), now)
    return outputs


def test_a_camera_mounted_off_its_parameters_is_reported_with_both_numbers():
    # The camera is 5 cm higher and 2 deg steeper than camera_height / camera_pitch say.
    pose = optical_pose(height=HEIGHT + 0.05, pitch=PITCH + math.radians(2.0))
    live = LiveFusion(config())
    run(live, millimetres(box_depth(CAMERA, pose, [BOX])), MOUNT_CHECK_FRAMES)
    health = live.health(MOUNT_CHECK_FRAMES / 10 + 0.05)
    assert (health.level, health.state) == (Level.WARN, State.MOUNT_MISMATCH)
    assert 'height 0.450 m, pitch 22.0' in health.message  # the floor's
    assert 'height 0.400 m, pitch 20.00 deg' in health.message  # the mounting's
    assert health.values['camera as mounted'].startswith('height 0.400 m')


def test_a_right_mounting_is_not_reported_and_fewer_frames_are_not_enough():
    right = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    live = LiveFusion(config())
    run(live, right, MOUNT_CHECK_FRAMES)
    health = live.health(MOUNT_CHECK_FRAMES / 10 + 0.05)
    assert (health.level, health.state) == (Level.OK, State.FUSING)
    assert health.values['ground estimate'] == f'{MOUNT_CHECK_FRAMES} frames estimated, 0 fell back'
    off = optical_pose(height=HEIGHT + 0.05, pitch=PITCH + math.radians(2.0))
    live = LiveFusion(config())
    run(live, millimetres(box_depth(CAMERA, off, [BOX])), MOUNT_CHECK_FRAMES - 1)
    assert live.health(MOUNT_CHECK_FRAMES / 10).state is State.FUSING


@pytest.mark.parametrize('ground_estimate', [True, False])
def test_the_node_takes_the_imu(ground_estimate):
    pitched = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    tilt = Transform.from_rpy(0.0, math.radians(2.0), 0.0).rotation
    live = LiveFusion(config(ground_estimate=ground_estimate, imu_topic='/imu'))
    outputs = run(live, pitched, 3, imu=tilt)
    assert len(outputs) == 3
    for output in outputs:
        assert output.depth_scan is not None
        assert score(scan_from_cdr(output.depth_scan)) == (0.0, 1.0)
    live = LiveFusion(config(ground_estimate=ground_estimate))
    live.on_imu(b'\x00\x01\x00\x00garbage')
    assert live.stream.counts.malformed == {'imu': 1}
