"""The node's Foxglove live view: a real foxglove-sdk server, a real WebSocket client."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import time

import pytest

from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.ros.live_view import make_view
from tests.support import REPOSITORY

pytest.importorskip('rclpy')
pytest.importorskip('foxglove')
websockets = pytest.importorskip('websockets')

pytestmark = pytest.mark.ros

SUBPROTOCOL = 'foxglove.sdk.v1'  # the WebSocket subprotocol foxglove-sdk servers speak
EXPECTED = {
    '/scan': 'sensor_msgs/msg/LaserScan',
    '/scan_fused': 'sensor_msgs/msg/LaserScan',
    '/scan_depth': 'sensor_msgs/msg/LaserScan',
    '/camera/depth/image_raw': 'sensor_msgs/msg/Image',
    '/tf': 'tf2_msgs/msg/TFMessage',
    '/tf_static': 'tf2_msgs/msg/TFMessage',
}


async def advertised(url: str, timeout: float = 10.0) -> dict[str, dict]:
    """Channels the server advertises to a fresh client: topic -> channel."""
    channels: dict[str, dict] = {}
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as client:
        assert client.subprotocol == SUBPROTOCOL
        deadline = time.monotonic() + timeout
        while not set(EXPECTED) <= set(channels) and time.monotonic() < deadline:
            message = await asyncio.wait_for(client.recv(), timeout)
            if isinstance(message, str):
                body = json.loads(message)
                if body.get('op') == 'advertise':
                    channels.update({c['topic']: c for c in body['channels']})
    return channels


def test_node_serves_its_topics_to_a_foxglove_client(tmp_path):
    env = {
        **os.environ,
        'ROS_DOMAIN_ID': str(180 + os.getpid() % 20),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
    }
    log = tmp_path / 'node.log'
    with log.open('w') as out:
        node = subprocess.Popen(
            [sys.executable, '-m', 'scanfuse.ros.node', '--foxglove', '0'],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + 60
        while (found := re.search(r'Foxglove live view on (ws://\S+)', log.read_text())) is None:
            assert node.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        url = found.group(1)
        assert url.startswith('ws://127.0.0.1:')  # loopback unless --foxglove-host says otherwise
        channels = asyncio.run(advertised(url))
    finally:
        node.terminate()
        node.wait(timeout=20)
    for topic, msgtype in EXPECTED.items():
        assert channels[topic]['schemaName'] == msgtype
        assert channels[topic]['encoding'] == 'cdr'
        assert channels[topic]['schemaEncoding'] == 'ros2msg'
    assert 'float32[] ranges' in channels['/scan_fused']['schema']


def test_a_busy_port_is_a_config_error():
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ConfigError, match=r'cannot serve Foxglove on 127\.0\.0\.1'):
            make_view(FusionConfig(), port)


def test_the_layout_shows_lidar_fused_and_remembered_scans_in_different_colours():
    layout = json.loads((REPOSITORY / 'examples' / 'foxglove_layout.json').read_text())
    panels = layout['configById']
    scene = next(config for name, config in panels.items() if name.startswith('3D!'))
    lidar, fused = scene['topics']['/scan'], scene['topics']['/scan_fused']
    assert lidar['visible']
    assert fused['visible']
    assert lidar['colorMode'] == fused['colorMode'] == 'flat'
    assert lidar['flatColor'] != fused['flatColor']
    # The remembered obstacles in their own colour, on the topic the node publishes them on.
    memory = scene['topics'][FusionConfig().memory_scan_topic]
    assert memory['visible']
    assert memory['flatColor'] not in {lidar['flatColor'], fused['flatColor']}
    image = next(config for name, config in panels.items() if name.startswith('Image!'))
    assert image['imageMode']['imageTopic'] == '/camera/depth/image_raw'
    assert set(layout['layout'].values()) >= set(panels)
