"""End-to-end latency of the live node over DDS beside a do-nothing relay, its CPU use,
and the time from starting the node's process to its first fused scan.

This process publishes an 848x480 16UC1 depth image at 30 Hz (with CameraInfo) and a
1080-reading LaserScan at 10 Hz (best effort, like the drivers) from before the node
starts, and subscribes /scan_fused. In the same run a relay process (rclpy, raw bytes in
and out, nothing else: `tests.support.loopback relay`; started, and relaying, before the
node is) republishes /scan on /scan_relay,
so the node's latency can be read against what DDS and rclpy alone cost on this machine
at this moment. Latency is from publishing a LiDAR scan to receiving the output with the
same stamp (one monotonic clock), DDS both ways. CPU is the node's user + system time
over the measured seconds (100 % = one core), and the relay's over the same seconds: what
rclpy and DDS alone cost for one 10 Hz scan in and out (the relay reads neither the depth
images nor CameraInfo).

Start-up: the publishers (and the relay) are up for `SETTLE_S` first, as a robot's drivers
are; then from just before `Popen` of `python -m scanfuse.ros.node` to the first message on
/scan_fused, received by this process's subscription (up before the node starts), that
differs from the LiDAR's bytes (a fused scan, not a pass-through). It holds the Python
start-up and imports (a warm install: compiled bytecode and numba's cache present), rclpy
and DDS start, the kernels loaded from numba's cache, DDS discovery with this process's
publishers, the camera's tables and the first pairing. "Node ready" is the wall-clock stamp
of the node's own "fusing ..." log line (every endpoint created, kernels loaded, about to
spin), against the wall clock at `Popen`: the rest up to the first fused scan is DDS
discovery and the first pair. The start-up trials (the node alone with this process's
publishers, no relay, started at phases spread over one announcement period) run under the
tests' `LOCALHOST` discovery range (no multicast, off the network), and once under ROS 2's
default `SUBNET` (multicast), each on this run's own domain; then the relay is started in
the node's place, at the same phases: its first relayed scan is what rclpy and DDS alone
take. Fast DDS (the rmw of the wheels) matches a late-joining participant with one that has
run for a while either at once or only at the older one's next periodic announcement (every
3 s by default): the older one answers a new participant's first announcement once, and
when that answer does not make the match, more announcements from the new participant
(1 or 20 instead of the default 5; a bare rclpy subscriber, 30 starts each, outside this
benchmark) change nothing. Announcing more often on the older side does: the last two
start-up rows put the drivers in a process of their own (`start_with_drivers`), once with
Fast DDS's defaults and once with every process announcing every 0.5 s
(`examples/fastdds_announce.xml`).
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.highlevel import AnyReader
from tests.support import with_repository_on_path
from tests.support.synthetic import Scene

from benchmarks.common import Row, median_seconds
from scanfuse.config import FusionConfig
from scanfuse.pipeline import FusionPipeline
from scanfuse.ros.messages import camera_to_cdr, depth_to_cdr, scan_from_cdr, scan_to_cdr, typestore
from scanfuse.scan import Scan

if TYPE_CHECKING:
    from collections.abc import Callable

SECONDS = 12.0
WARM_UP_S = 2.0
START_TIMEOUT_S = 60.0
STARTS = 10  # start-up trials of each kind
# The publishers run this long before the node starts, as a robot's drivers have: past the
# quick announcements a new DDS participant sends in its first half second, which find a
# node that starts meanwhile at once (a robot's node never starts that early).
SETTLE_S = 2.0
# Fast DDS's default period of participant announcements: the start-up trials start the node
# at phases spread over one period after the publishers' start (the wait for discovery
# depends on that phase).
ANNOUNCE_PERIOD_S = 3.0
SCAN_HZ, DEPTH_HZ = 10.0, 30.0
NODE_PARAMS = {'camera_x': 0.1}
# The node's console lines carry wall-clock stamps in this format (rcutils'); "fusing" is the
# last line of its start-up.
LOG_FORMAT = '[{severity}] [{time}] [{name}]: {message}'
_READY = re.compile(r'\[INFO\] \[(\d+\.\d+)\] \[scanfuse\]: fusing ')


def _cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text(encoding='utf-8').rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _node_env(env: dict[str, str]) -> dict[str, str]:
    """The node's environment: an installed package's bytecode is compiled at install, so
    bytecode is written and read (under a cache directory of the benchmark's own) even where
    PYTHONDONTWRITEBYTECODE is set for this process."""
    cache = Path(tempfile.gettempdir()) / 'scanfuse-bench-pycache'
    node_env = {k: v for k, v in env.items() if k != 'PYTHONDONTWRITEBYTECODE'}
    return {
        **node_env,
        'PYTHONPYCACHEPREFIX': str(cache),
        'RCUTILS_CONSOLE_OUTPUT_FORMAT': LOG_FORMAT,
    }


def _env(discovery: str = 'LOCALHOST') -> dict[str, str]:
    return with_repository_on_path(
        {
            **os.environ,
            'ROS_DOMAIN_ID': str(200 + os.getpid() % 30),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': discovery,
        }
    )


def warm_install() -> None:
    """Import the node once as it will be started, so its bytecode and numba's cache are
    written (what installing the package and a first start leave behind)."""
    subprocess.run(
        [sys.executable, '-c', 'import scanfuse.ros.node'], env=_node_env(_env()), check=True
    )


def _ready_seconds(log: Path, launched_wall: float) -> float:
    """Seconds from `Popen` (wall clock) to the node's "fusing ..." line; NaN without one."""
    match = _READY.search(log.read_text(encoding='utf-8', errors='replace'))
    return float(match.group(1)) - launched_wall if match else float('nan')


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


def kernel_seconds() -> float:
    """The fusion alone (obstacle method, this scene) in this process: the node's floor."""
    scene, lidar = _scene_and_scan()
    pipeline = FusionPipeline(FusionConfig(**NODE_PARAMS))
    depth = scene.depth_mm()
    return median_seconds(lambda: pipeline.fuse(lidar, depth, scene.camera), repeat=15)


class SceneDrivers:
    """This benchmark's scene published as a robot's drivers would: /scan at SCAN_HZ, depth
    and CameraInfo at DEPTH_HZ (a third of a frame after the first scan), stamped now."""

    def __init__(self, node: Any, start: float) -> None:
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo, Image, LaserScan

        self.scene, self.lidar = _scene_and_scan()
        self.store, self.depth = typestore(), self.scene.depth_mm()
        data = qos_profile_sensor_data
        self.scans = node.create_publisher(LaserScan, '/scan', data)
        self.images = node.create_publisher(Image, '/camera/depth/image_raw', data)
        self.infos = node.create_publisher(CameraInfo, '/camera/depth/camera_info', data)
        self.next_scan, self.next_depth = start, start + 1.0 / DEPTH_HZ / 3

    def publish_due(self, now: float, on_scan: Callable[[int, bytes], None] | None = None) -> bool:
        """Publish what is due at `now` (monotonic); True when a scan went out (`on_scan`
        sees its stamp and bytes just before)."""
        if now >= self.next_depth:
            stamp = time.time_ns()
            store = self.store
            self.images.publish(
                depth_to_cdr(self.depth, frame_id='cam', stamp_ns=stamp, store=store)
            )
            self.infos.publish(camera_to_cdr(self.scene.camera, stamp_ns=stamp, store=store))
            self.next_depth += 1.0 / DEPTH_HZ
        if now < self.next_scan:
            return False
        stamp = time.time_ns()
        raw = scan_to_cdr(self.lidar.with_ranges(self.lidar.ranges, stamp_ns=stamp), self.store)
        if on_scan is not None:
            on_scan(stamp, raw)
        self.scans.publish(raw)
        self.next_scan += 1.0 / SCAN_HZ
        return True

    def next_due(self) -> float:
        return min(self.next_scan, self.next_depth)


def _node_command(pair_wait: float) -> list[str]:
    """The node as the benchmark starts it: NODE_PARAMS and `pair_wait`."""
    params = [f'{name}:={value}' for name, value in {**NODE_PARAMS, 'pair_wait': pair_wait}.items()]
    return [
        sys.executable, '-m', 'scanfuse.ros.node', '--ros-args',
        *(arg for param in params for arg in ('-p', param)),
    ]  # fmt: skip


def measure(
    pair_wait: float,
    seconds: float = SECONDS,
    *,
    relay: bool = True,
    settle: float = SETTLE_S,
    discovery: str = 'LOCALHOST',
    started: str = 'node',
) -> dict[str, object]:
    """Latencies (node, relay), node CPU share, first fused scan, node ready and scans sent,
    one run; `seconds` 0: stop at the first fused scan (start-up only, no relay needed).
    `started` 'relay' (start-up only): the relay is started in the node's place, and its
    first relayed scan counts as the first output (rclpy and DDS alone, no scanfuse)."""
    if started not in ('node', 'relay') or (started == 'relay' and (relay or seconds)):
        msg = f'started {started!r}: "node", or "relay" for a start-up alone (relay=False)'
        raise ValueError(msg)
    import rclpy
    from sensor_msgs.msg import LaserScan

    env = _env(discovery)
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')})
    rclpy.init()
    node = rclpy.create_node('scanfuse_bench')
    sent: dict[int, float] = {}
    sent_raw: dict[int, bytes] = {}
    latencies: dict[str, list[float]] = {'node': [], 'relay': []}
    first_fused: list[float] = []

    def on_scan(stamp: int, raw: bytes) -> None:
        sent[stamp] = time.monotonic()
        if not first_fused:
            sent_raw[stamp] = raw

    def on_output(kind: str):  # noqa: ANN202
        def callback(raw: bytes) -> None:
            stamp = scan_from_cdr(raw).stamp_ns
            if stamp in sent:
                latencies[kind].append(time.monotonic() - sent[stamp])
            if first_fused or stamp not in sent_raw:
                return
            if started == 'relay' or (kind == 'node' and raw != sent_raw[stamp]):
                first_fused.append(time.monotonic())

        return callback

    node.create_subscription(LaserScan, '/scan_fused', on_output('node'), 10, raw=True)
    node.create_subscription(LaserScan, '/scan_relay', on_output('relay'), 10, raw=True)
    log_dir = tempfile.TemporaryDirectory(prefix='scanfuse-bench-node-')
    log = Path(log_dir.name) / 'node.log'
    log_file = log.open('wb')
    processes: list[subprocess.Popen[bytes]] = []
    relay_command = [
        sys.executable,
        '-m',
        'tests.support.loopback',
        'relay',
        '/scan',
        '/scan_relay',
    ]
    if relay:
        # Up and relaying before the node starts, as a robot's other nodes are: its own
        # start-up and discovery are not the node's.
        processes.append(
            subprocess.Popen(  # noqa: S603 - our own interpreter and module
                relay_command,
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
    launched_wall = launched = float('nan')
    node_process: subprocess.Popen[bytes] | None = None
    cpu = relay_cpu = float('nan')
    relay_start = float('nan')
    try:
        began = time.monotonic()
        drivers = SceneDrivers(node, began)
        cpu_start = wall_start = measure_from = None
        scans = 0
        while True:
            now = time.monotonic()
            settled = now >= began + settle and (not relay or latencies['relay'])
            if node_process is None and settled:
                launched_wall = time.time()
                launched = now = time.monotonic()
                node_process = subprocess.Popen(  # noqa: S603 - our own interpreter and module
                    relay_command if started == 'relay' else _node_command(pair_wait),
                    env=_node_env(env),
                    stdout=log_file,
                    stderr=subprocess.STDOUT,
                )
                processes.append(node_process)
            if first_fused and not seconds:
                break
            if measure_from is None and first_fused:
                measure_from = now + WARM_UP_S
            if (
                measure_from is None
                and now > (launched if node_process else began) + START_TIMEOUT_S
            ):
                what = 'starting the node' if node_process else 'starting the relay'
                msg = f'no fused scan within {START_TIMEOUT_S} s of {what}'
                raise RuntimeError(msg)
            if measure_from is not None and cpu_start is None and now >= measure_from:
                assert node_process is not None
                cpu_start, wall_start = _cpu_seconds(node_process.pid), now
                if relay:
                    relay_start = _cpu_seconds(processes[0].pid)
                for values in latencies.values():
                    values.clear()
            if wall_start is not None and now >= wall_start + seconds:
                break
            if drivers.publish_due(now, on_scan):
                scans += cpu_start is not None
            rclpy.spin_once(node, timeout_sec=max(0.0, drivers.next_due() - now))
        if seconds:
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.05)
            assert cpu_start is not None
            assert wall_start is not None
            assert node_process is not None
            elapsed = time.monotonic() - wall_start
            cpu = (_cpu_seconds(node_process.pid) - cpu_start) / elapsed
            if relay:
                relay_cpu = (_cpu_seconds(processes[0].pid) - relay_start) / elapsed
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for process in processes:
            process.terminate()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()  # the relay has no SIGTERM handler of its own
                process.wait(timeout=10)
        log_file.close()
        ready = _ready_seconds(log, launched_wall)
        log_dir.cleanup()
    return {
        'latencies': latencies,
        'cpu': cpu,
        'relay_cpu': relay_cpu,
        'first_fused_s': first_fused[0] - launched,
        'ready_s': ready,
        'scans': scans,
    }


# The drivers of `start_with_drivers`, in a process of their own, until killed.
_DRIVERS = """
import time
import rclpy
from benchmarks.bench_node import SceneDrivers
rclpy.init()
node = rclpy.create_node('scanfuse_bench_drivers')
drivers = SceneDrivers(node, time.monotonic())
while True:
    drivers.publish_due(time.monotonic())
    rclpy.spin_once(node, timeout_sec=max(0.0, drivers.next_due() - time.monotonic()))
"""
DRIVER_PROFILE = Path(__file__).resolve().parent.parent / 'examples' / 'fastdds_announce.xml'
# How long the recorder of `start_with_drivers` listens after the node's start.
RECORD_AFTER_START_S = 6.0


def start_with_drivers(settle: float, profile: Path | None) -> float:
    """Process start to first fused scan (seconds; +Inf: none within RECORD_AFTER_START_S)
    with the drivers in a process of their own (`_DRIVERS`) and the first fused scan
    received by `tests.support.loopback record`, both up `settle` seconds before the node
    starts; LOCALHOST, pair_wait 0. With `profile` every process loads that Fast DDS
    profile (`DRIVER_PROFILE`: announcing every 0.5 s, the cure for the wait at discovery
    the README names); without, Fast DDS's defaults."""
    env = _env()
    if profile is not None:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = env['FASTDDS_DEFAULT_PROFILES_FILE'] = str(profile)
    _, lidar = _scene_and_scan()
    with tempfile.TemporaryDirectory(prefix='scanfuse-bench-announce-') as folder:
        work = Path(folder)
        ready, stop, bag = work / 'ready', work / 'stop', work / 'fused.mcap'
        recorder = subprocess.Popen(  # noqa: S603 - our own interpreter and module
            [sys.executable, '-m', 'tests.support.loopback', 'record', str(bag), '--topic',
             '/scan_fused', '--duration', str(START_TIMEOUT_S), '--ready', str(ready),
             '--stop', str(stop)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        drivers = subprocess.Popen(  # noqa: S603 - our own interpreter and script
            [sys.executable, '-c', _DRIVERS],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        node_process = None
        try:
            began = time.monotonic()
            while not ready.exists():
                if time.monotonic() > began + START_TIMEOUT_S:
                    msg = 'the recorder did not start'
                    raise RuntimeError(msg)
                time.sleep(0.01)
            time.sleep(max(0.0, began + settle - time.monotonic()))
            launched_ns = time.monotonic_ns()
            node_process = subprocess.Popen(  # noqa: S603 - our own interpreter and module
                _node_command(0.0),
                env=_node_env(env),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            time.sleep(RECORD_AFTER_START_S)
            stop.write_text('stop', encoding='utf-8')
            recorder.wait(timeout=START_TIMEOUT_S)
        finally:
            for process in (node_process, drivers, recorder):
                if process is not None and process.poll() is None:
                    process.terminate()
                    try:
                        process.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        process.kill()
                        process.wait(timeout=10)
        with AnyReader([bag]) as reader:
            for _, log_ns, raw in reader.messages():
                # A fused scan, not the LiDAR's passed through (before the first pair).
                if not np.array_equal(scan_from_cdr(raw).ranges, lidar.ranges, equal_nan=True):
                    return (log_ns - launched_ns) / 1e9
    return math.inf


def _spread(first: list[float]) -> str:
    """A start-up row's note: the worst start and how many came within the 2 s target."""
    return f'median; worst {max(first):.2f} s, within 2 s {sum(f <= 2.0 for f in first)}'


def run() -> list[Row]:
    kernel = kernel_seconds()
    warm_install()
    rows = [Row('node', 'fusion alone (848x480, 1080 readings)', kernel, 'in-process floor')]
    for pair_wait in (0.0, 0.05):
        result = measure(pair_wait)
        label = f'pair_wait {pair_wait:g} s'
        latencies: dict[str, list[float]] = result['latencies']  # type: ignore[assignment]
        node = np.array(latencies['node'])
        relay = np.array(latencies['relay'])
        scans = result['scans']
        note = f'{len(node)}/{scans} scans back; 848x480 @30 Hz, 1080 @10 Hz'
        p50, relay_p50 = float(np.percentile(node, 50)), float(np.percentile(relay, 50))
        over = p50 - relay_p50 - kernel
        rows += [
            Row('node', f'latency p50, {label}', p50, note),
            Row('node', f'latency p99, {label}', float(np.percentile(node, 99)), note),
            Row('node', f'relay latency p50 (same run), {label}', relay_p50, f'{len(relay)} back'),
            Row('node', f'relay latency p99 (same run), {label}', float(np.percentile(relay, 99))),
            Row('node', f'node p50 - relay p50 - fusion, {label}', over, 'target <= 0.5 ms'),
            *(
                Row('node', f'{what}, {label}', float(result[key]), why, unit='share')  # type: ignore[arg-type]
                for what, key, why in (
                    ('node CPU (share of one core)', 'cpu', 'user + system; target <= 6 %'),
                    (
                        'relay CPU (same run)',
                        'relay_cpu',
                        'user + system; /scan in and out only (10 Hz)',
                    ),
                )
            ),
            Row(
                'node',
                f'process start to first fused scan, {label}',
                float(result['first_fused_s']),  # type: ignore[arg-type]
                f'this run (node ready {float(result["ready_s"]):.2f} s; '  # type: ignore[arg-type]
                'warm install; target <= 2 s)',
            ),
        ]
    # Both pair_wait values under the tests' LOCALHOST; ROS 2's default SUBNET once, to tell
    # whether a slow start is LOCALHOST's (no multicast) or Fast DDS's discovery as such;
    # and the do-nothing relay started in the node's place: what rclpy and DDS alone take.
    # Interleaved, phase by phase, so each sees the same moments of the machine.
    kinds = (
        ('node', 'LOCALHOST', 0.0),
        ('node', 'LOCALHOST', 0.05),
        ('node', 'SUBNET', 0.0),
        ('relay', 'LOCALHOST', 0.0),
    )
    starts: dict[tuple[str, str, float], list[dict[str, object]]] = {kind: [] for kind in kinds}
    # And the drivers in a process of their own, announcing at Fast DDS's default period and
    # every 0.5 s (`DRIVER_PROFILE`, every process).
    apart: dict[str, list[float]] = {'default': [], 'profile': []}
    for i in range(STARTS):
        settle = SETTLE_S + ANNOUNCE_PERIOD_S * i / STARTS
        for started, discovery, pair_wait in kinds:
            starts[started, discovery, pair_wait].append(
                measure(
                    pair_wait,
                    0.0,
                    relay=False,
                    settle=settle,
                    discovery=discovery,
                    started=started,
                )
            )
        apart['default'].append(start_with_drivers(settle, None))
        apart['profile'].append(start_with_drivers(settle, DRIVER_PROFILE))
    for (started, discovery, pair_wait), results in starts.items():
        first = [float(start['first_fused_s']) for start in results]  # type: ignore[arg-type]
        spread = _spread(first)
        if started == 'relay':
            name = f'the relay in its place: process start to first relayed scan, {discovery}'
            note = f'{spread}/{STARTS} (rclpy and DDS alone)'
        else:
            name = f'process start to first fused scan, {discovery}, pair_wait {pair_wait:g} s'
            ready = [float(start['ready_s']) for start in results]  # type: ignore[arg-type]
            note = (
                f'{spread}/{STARTS}; node ready median {np.median(ready):.2f} s, worst '
                f'{max(ready):.2f} s (the rest: DDS discovery, first pair)'
            )
        rows.append(Row('node', f'{name}, {STARTS} starts', float(np.median(first)), note))
    announcing = {
        'default': f'every {ANNOUNCE_PERIOD_S:g} s (default)',
        'profile': 'every 0.5 s (examples/fastdds_announce.xml)',
    }
    for kind, first in apart.items():
        rows.append(
            Row(
                'node',
                f'process start to first fused scan, drivers a process of their own announcing '
                f'{announcing[kind]}, LOCALHOST, {STARTS} starts',
                float(np.median(first)),
                f'{_spread(first)}/{STARTS}',
            )
        )
    return rows


if __name__ == '__main__':
    for row in run():
        value = f'{row.median_s:9.1%}' if row.unit == 'share' else f'{row.median_s * 1e3:9.3f} ms'
        print(f'{row.name:50s} {value}   {row.note}')
