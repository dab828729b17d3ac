"""End-to-end latency of the live node over DDS on loopback, and the node's CPU use.

This process publishes an 848x480 16UC1 depth image at 30 Hz and a 1080-reading
LaserScan at 10 Hz (best effort, like the drivers) and subscribes /scan_fused;
the node runs as its own process. Latency is from publishing a LiDAR scan to
receiving the fused scan with the same stamp (both clocks are this machine's
monotonic clock), so it includes DDS both ways. CPU is the node's user + system
time over the measured seconds (100 % = one core).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tests.support.synthetic import Scene

from benchmarks.common import Row
from scanfuse.ros.messages import camera_to_cdr, depth_to_cdr, scan_from_cdr, scan_to_cdr, typestore
from scanfuse.scan import Scan

SECONDS = 12.0
WARM_UP_S = 2.0
SCAN_HZ, DEPTH_HZ = 10.0, 30.0


def _cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text(encoding='utf-8').rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _scene_and_scan() -> tuple[Scene, Scan]:
    scene = Scene(width=848, height=480, focal=425.0, readings=1080)
    lidar = Scan(
        angle_min=scene.angle_min,
        angle_max=scene.angle_min + scene.angle_increment * (scene.readings - 1),
        angle_increment=scene.angle_increment,
        range_min=0.05,
        range_max=scene.lidar_range_max,
        ranges=scene.lidar_ranges(),
        scan_time=1.0 / SCAN_HZ,
        frame_id='laser',
    )
    return scene, lidar


def measure(pair_wait: float) -> tuple[list[float], float, int]:
    """(latencies s, node CPU share, scans sent) for one run of the node."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image, LaserScan

    scene, lidar = _scene_and_scan()
    store = typestore()
    depth = scene.depth_mm()
    camera = scene.camera
    env = {
        **os.environ,
        'ROS_DOMAIN_ID': str(200 + os.getpid() % 30),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
    }
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')})
    node_process = subprocess.Popen(  # noqa: S603 - our own interpreter and module
        [
            sys.executable,
            '-m',
            'scanfuse.ros.node',
            '--ros-args',
            '-p',
            f'pair_wait:={pair_wait}',
            '-p',
            'camera_x:=0.1',
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    rclpy.init()
    node = rclpy.create_node('scanfuse_bench')
    scan_pub = node.create_publisher(LaserScan, '/scan', qos_profile_sensor_data)
    depth_pub = node.create_publisher(Image, '/camera/depth/image_raw', qos_profile_sensor_data)
    info_pub = node.create_publisher(
        CameraInfo, '/camera/depth/camera_info', qos_profile_sensor_data
    )
    sent: dict[int, float] = {}
    latencies: list[float] = []

    def on_fused(raw: bytes) -> None:
        stamp = scan_from_cdr(raw).stamp_ns
        if stamp in sent:
            latencies.append(time.monotonic() - sent.pop(stamp))

    node.create_subscription(LaserScan, '/scan_fused', on_fused, 10, raw=True)
    try:
        deadline = time.monotonic() + 60
        while scan_pub.get_subscription_count() == 0 or node.count_publishers('/scan_fused') == 0:
            rclpy.spin_once(node, timeout_sec=0.05)
            if time.monotonic() > deadline:
                msg = 'the node did not come up within 60 s'
                raise RuntimeError(msg)
        start = time.monotonic()
        next_scan, next_depth = start, start + 1.0 / DEPTH_HZ / 3
        cpu_start = wall_start = None
        scans = 0
        while (now := time.monotonic()) < start + WARM_UP_S + SECONDS:
            if cpu_start is None and now >= start + WARM_UP_S:
                cpu_start, wall_start = _cpu_seconds(node_process.pid), now
                latencies.clear()
            if now >= next_depth:
                stamp = time.time_ns()
                depth_pub.publish(depth_to_cdr(depth, frame_id='cam', stamp_ns=stamp, store=store))
                info_pub.publish(camera_to_cdr(camera, stamp_ns=stamp, store=store))
                next_depth += 1.0 / DEPTH_HZ
            if now >= next_scan:
                stamp = time.time_ns()
                raw = scan_to_cdr(lidar.with_ranges(lidar.ranges, stamp_ns=stamp), store)
                sent[stamp] = time.monotonic()
                scan_pub.publish(raw)
                scans += cpu_start is not None
                next_scan += 1.0 / SCAN_HZ
            rclpy.spin_once(node, timeout_sec=max(0.0, min(next_scan, next_depth) - now))
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        assert cpu_start is not None
        assert wall_start is not None
        cpu = (_cpu_seconds(node_process.pid) - cpu_start) / (time.monotonic() - wall_start)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        node_process.terminate()
        node_process.wait(timeout=10)
    return latencies, cpu, scans


def run() -> list[Row]:
    rows = []
    for pair_wait in (0.0, 0.05):
        latencies, cpu, scans = measure(pair_wait)
        label = f'pair_wait {pair_wait:g} s'
        values = np.array(latencies)
        note = f'{len(latencies)}/{scans} scans back; 848x480 @30 Hz, 1080 @10 Hz'
        rows += [
            Row('node', f'latency p50, {label}', float(np.percentile(values, 50)), note),
            Row('node', f'latency p99, {label}', float(np.percentile(values, 99)), note),
            Row(
                'node', f'node CPU (share of one core), {label}', cpu, 'user + system', unit='share'
            ),
        ]
    return rows


if __name__ == '__main__':
    for row in run():
        print(f'{row.name:45s} {row.median_s * 1e3:9.3f} ms   {row.note}')
