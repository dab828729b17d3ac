"""The base's tilt from an IMU (issue 25): a pitched or rolled body with the ground
estimate off gives the flat-floor result, and bad IMU messages change nothing.

Scenes and scores are `tests/convert/test_ground.py`'s (issue 25's analytic scene); the
IMU's orientation is the body's tilt, as REP-145 has it (the IMU frame's attitude against
gravity), worked out from the same roll and pitch that place the camera.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import pytest

from scanfuse.errors import InputError
from scanfuse.imu import base_tilt
from scanfuse.stream import FusionStream
from scanfuse.transforms import Transform
from tests.support.ground_scene import (
    BOX,
    CAMERA,
    NS,
    config,
    lidar_scan,
    optical_pose,
    score,
)
from tests.support.render import box_depth, millimetres

if TYPE_CHECKING:
    import numpy as np

IMU_PERIOD_NS = 5_000_000  # 200 Hz


def body_quaternion(roll_deg: float, pitch_deg: float) -> tuple[float, float, float, float]:
    return Transform.from_rpy(math.radians(roll_deg), math.radians(pitch_deg), 0.0).rotation


def fused_with_imu(
    depth: np.ndarray,
    orientation,
    *,
    imu_until_ns: int | None = None,
    frame_id: str = 'base_link',
    **changes: object,
):
    """The depth scan of one frame at 0.1 s, an IMU at 200 Hz from 0 to `imu_until_ns`."""
    stream: FusionStream[int] = FusionStream(config(**changes))
    stream.add_camera_info(CAMERA)
    stamp = NS // 10
    for imu_ns in range(0, (imu_until_ns or stamp + NS // 100) + 1, IMU_PERIOD_NS):
        stream.add_imu(imu_ns, orientation, frame_id)
    stream.add_depth(stamp, depth, stamp)
    (out,) = stream.add_scan(lidar_scan(stamp), 0, stamp + 1)
    assert out.depth_scan is not None
    return out.depth_scan, stream


TILTS = {'pitched 2 deg nose-down': (0.0, 2.0), 'pitched 2 deg nose-up': (0.0, -2.0),
         'rolled 2 deg': (2.0, 0.0), 'rolled -2 deg and pitched 1.5 deg': (-2.0, 1.5)}  # fmt: skip


@pytest.mark.parametrize('tilt', TILTS.values(), ids=TILTS.keys())
def test_with_an_imu_and_the_ground_estimate_off_a_tilted_body_gives_the_flat_floor_result(tilt):
    roll, pitch = tilt
    depth = millimetres(box_depth(CAMERA, optical_pose(body_roll=roll, body_pitch=pitch), [BOX]))
    scan, stream = fused_with_imu(depth, body_quaternion(roll, pitch), ground_estimate=False)
    assert score(scan) == (0.0, 1.0)
    without, _ = fused_with_imu(depth, body_quaternion(0.0, 0.0), ground_estimate=False)
    assert score(without)[0] > 0.1  # the same frame, an IMU saying level: the floor
    assert stream.counts.malformed == {}


def test_with_an_imu_and_the_ground_estimate_on_a_tilted_body_gives_the_flat_floor_result():
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    scan, _ = fused_with_imu(depth, body_quaternion(0.0, 2.0))
    assert score(scan) == (0.0, 1.0)


def test_an_imu_in_its_own_frame_is_placed_on_the_base_by_tf():
    from scanfuse.frames import StampedTransform

    # The IMU is mounted upside down (rolled pi) on the base: its attitude is the base's
    # times that mounting.
    mount = Transform.from_rpy(math.pi, 0.0, 0.0, (0.1, 0.0, 0.2))
    body = Transform.from_rpy(0.0, math.radians(2.0), 0.0)
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    stream: FusionStream[int] = FusionStream(config(ground_estimate=False, use_tf=True))
    stream.add_transforms(
        [StampedTransform('base_link', 'imu_link', mount.translation, mount.rotation)],
        static=True,
        odometry=False,
    )
    stream.add_camera_info(CAMERA)
    for imu_ns in range(0, NS // 10 + 1, IMU_PERIOD_NS):
        stream.add_imu(imu_ns, (body @ mount).rotation, 'imu_link')
    stream.add_depth(NS // 10, depth, NS // 10)
    (out,) = stream.add_scan(lidar_scan(NS // 10), 0, NS // 10 + 1)
    assert out.depth_scan is not None
    assert score(out.depth_scan) == (0.0, 1.0)


BAD = {
    'NaN': (math.nan, 0.0, 0.0, 1.0),
    'zero (no orientation)': (0.0, 0.0, 0.0, 0.0),
    'not a unit quaternion': (0.0, 0.5, 0.0, 0.5),
    'upside down': Transform.from_rpy(math.pi, 0.0, 0.0).rotation,
}


@pytest.mark.parametrize('orientation', BAD.values(), ids=BAD.keys())
def test_a_bad_imu_orientation_is_counted_and_changes_nothing(orientation):
    depth = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    scan, stream = fused_with_imu(depth, orientation, ground_estimate=False)
    assert stream.counts.malformed['imu'] > 0
    assert score(scan) == (0.0, 1.0)  # the flat floor as mounted


@pytest.mark.parametrize('orientation', BAD.values(), ids=BAD.keys())
def test_base_tilt_refuses_a_bad_orientation(orientation):
    with pytest.raises(InputError, match=r'unit quaternion|beyond 45 deg'):
        base_tilt(orientation, Transform())


def test_an_imu_that_stopped_is_not_used_and_the_ground_estimate_still_finds_the_floor():
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    # The IMU said "pitched 5 deg" until 20 ms, then fell silent: 80 ms before the frame.
    stale = body_quaternion(0.0, 5.0)
    scan, stream = fused_with_imu(depth, stale, imu_until_ns=20_000_000)
    assert stream.counts.imu_missed == 1
    assert score(scan) == (0.0, 1.0)
    off, stream = fused_with_imu(depth, stale, imu_until_ns=20_000_000, ground_estimate=False)
    assert stream.counts.imu_missed == 1
    assert score(off)[0] > 0.1  # untilted, as mounted: the floor (no stale 5 deg applied)


def test_the_tilt_at_a_frame_is_the_mean_of_the_samples_around_it():
    from scanfuse.imu import ImuHistory

    history = ImuHistory()
    # 2 deg of pitch with +-0.3 deg of noise, alternating, at 200 Hz around 1 s.
    for index in range(-10, 11):
        noise = 0.3 if index % 2 else -0.3
        history.add(
            NS + index * IMU_PERIOD_NS, base_tilt(body_quaternion(0.0, 2.0 + noise), Transform())
        )
    tilt = history.tilt_at(NS)
    assert tilt is not None
    roll, pitch, _ = tilt.rpy()
    # 9 samples within 20 ms: four +0.3, five -0.3 -> 2 - 0.3 / 9 deg
    assert math.degrees(pitch) == pytest.approx(2.0 - 0.3 / 9.0, abs=1e-6)
    assert roll == pytest.approx(0.0, abs=1e-9)
    assert history.tilt_at(NS + 200_000_000) is None  # 150 ms past the last sample


@pytest.mark.parametrize('grade', [12.0, 8.0])
def test_a_robot_standing_on_a_ramp_reports_the_box_on_it_and_not_the_ramp(grade):
    # The IMU gives the body's tilt against gravity: nose-up by the ramp's slope. The floor
    # the camera sees is the ramp the wheels stand on, the mounting's own plane, 4.8 or 7.1
    # deg from the level floor the IMU's tilt puts under the robot (beyond ground_max_tilt
    # on the 1:8 ramp): the ramp is floor and the box on it is the box.
    slope = math.degrees(math.atan(1.0 / grade))
    depth = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    scan, stream = fused_with_imu(depth, body_quaternion(0.0, -slope))
    assert score(scan) == (0.0, 1.0)
    assert stream.ground is not None
    assert stream.ground.counts.estimated == 1
