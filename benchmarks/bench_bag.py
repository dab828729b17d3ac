"""Offline fusion of a recorded bag: a 60 s recording through `fuse_bag`.

10 Hz LiDAR scans of 1080 readings, 30 Hz 848x480 16UC1 depth with CameraInfo and
/tf_static (the synthetic scene of tests.support.synthetic), written as an MCAP bag
into a temporary folder and fused into a new MCAP bag.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from pathlib import Path

from tests.support.synthetic import Scene, write_scene_bag

from benchmarks.common import Row
from scanfuse.ros.bag import fuse_bag

DURATION = 60.0
REPEAT = 3
SCENE = Scene(
    readings=1080,
    fov=1.5 * math.pi,
    width=848,
    height=480,
    focal=421.0,
    duration=DURATION,
    scan_hz=10.0,
    depth_hz=30.0,
)


def run() -> list[Row]:
    with tempfile.TemporaryDirectory(prefix='scanfuse-bench-bag-') as folder:
        source = write_scene_bag(Path(folder) / 'in', SCENE, storage='mcap')
        seconds = []
        reports = []
        for index in range(REPEAT):
            start = time.perf_counter()
            reports.append(fuse_bag(source, Path(folder) / f'out{index}', storage='mcap'))
            seconds.append(time.perf_counter() - start)
    median = statistics.median(seconds)
    report = reports[len(reports) // 2]
    messages = report.messages_read
    note = (
        f'{messages} msgs in, {report.messages_written} out: {messages / median:.0f} msg/s, '
        f'real-time factor {DURATION / median:.1f}x; per scan median '
        f'{report.median_scan_time_s * 1e3:.2f} ms, p99 {report.p99_scan_time_s * 1e3:.2f} ms'
    )
    return [Row('bag', 'fuse_bag 60 s mcap (600 scans, 1800 depth 848x480)', median, note)]


if __name__ == '__main__':
    for row in run():
        print(row)
