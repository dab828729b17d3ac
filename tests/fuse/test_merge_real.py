"""Algorithm 2 (merge) on the real Hokuyo recording (see ../shared/data/real/README.md).

The URG-class LiDAR of scan_tools writes 0 for an invalid reading (681 beams,
range_min 0.02 m, range_max 5.6 m). Issue 11 item 4: with the scan's range_min set to
0.0, as some driver configurations publish, those zeros became 0 m obstacles in the
fused scan. Each scan here is merged with a depth scan that sees nothing (NaN) except
a 1.0 m obstacle over a few slots, as the camera would in front of the robot.
"""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from scanfuse.fuse.merge import merge_scans
from scanfuse.ros.messages import scan_from_cdr

pytestmark = pytest.mark.real_data

HOKUYO = 'lidar/scan_tools/hokuyo_scan_matcher_demo_ros2_db3'


@pytest.fixture(scope='module')
def hokuyo_scans(real_data):
    with AnyReader([real_data / HOKUYO]) as reader:
        return [scan_from_cdr(bytes(raw)) for _, _, raw in reader.messages()]


def _depth_like(lidar):
    ranges = np.full(len(lidar), np.nan, np.float32)
    centre = len(lidar) // 2
    ranges[centre - 5 : centre + 5] = 1.0
    return lidar.with_ranges(ranges, range_min=0.2, range_max=3.0, frame_id='camera')


@pytest.mark.parametrize('published_range_min', [None, 0.0])
def test_no_driver_error_value_survives_the_merge(hokuyo_scans, published_range_min):
    assert len(hokuyo_scans) == 360  # README: 360 scans of 681 beams
    zeros_seen = 0
    for raw in hokuyo_scans:
        lidar = raw
        if published_range_min is not None:
            lidar = raw.with_ranges(raw.ranges, range_min=published_range_min)
        depth = _depth_like(lidar)
        fused = merge_scans(lidar, depth)
        zeros = raw.ranges == 0.0
        zeros_seen += int(zeros.sum())
        assert not (fused.ranges == 0.0).any()
        # The driver's zeros say nothing: NaN, unless the camera sees something there.
        assert np.isnan(fused.ranges[zeros & np.isnan(depth.ranges)]).all()
        finite = np.isfinite(fused.ranges)
        values = fused.ranges[finite]
        assert ((values >= fused.range_min) & (values <= fused.range_max)).all()
        # Every real LiDAR reading (inside the recording's own 0.02..5.6 m) stays or gets nearer.
        real = (raw.ranges >= raw.range_min) & (raw.ranges <= raw.range_max)
        assert (fused.ranges[real] <= raw.ranges[real]).all()
        np.testing.assert_array_equal(
            fused.ranges[real & np.isnan(depth.ranges)], raw.ranges[real & np.isnan(depth.ranges)]
        )
    # The premise: the recording has its zeros (35 a scan on average, 47 in the first).
    assert zeros_seen > 30 * len(hokuyo_scans)
