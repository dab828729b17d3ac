"""`scanfuse play`: what it plays (topics, QoS, offsets) and, over real DDS, the demo's two
commands: the node and `play --listen` on a recorded drive, /scan_fused counted back.

The DDS test runs in its own ROS_DOMAIN_ID with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosReliability

from scanfuse.errors import BagError
from scanfuse.ros.playback import TopicQos, choose_topics, read_recording
from scanfuse.sim.recording import LATCHED
from tests.support import with_repository_on_path
from tests.support.synthetic import Scene, scene_messages, write_bag, write_scene_bag

if TYPE_CHECKING:
    from pathlib import Path

pytest.importorskip('rclpy')

from scanfuse.app.demo import live_commands
from scanfuse.ros.play import PlayError, PlayOptions, StopRequest
from tests.support.loopback_domains import domain_id


def recorded_counts(bag: Path) -> dict[str, int]:
    """Messages per topic, read with rosbags (not with scanfuse's reader)."""
    counts: dict[str, int] = {}
    with AnyReader([bag]) as reader:
        for connection, _, _ in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    return counts


def test_qos_is_the_recorded_one_and_tf_static_is_latched(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer

    from scanfuse.ros.messages import typestore

    best_effort = LATCHED._replace(
        reliability=QosReliability.BEST_EFFORT, durability=QosDurability.VOLATILE, depth=5
    )
    offered = {'/scan': [best_effort], '/tf_static': [], '/camera/depth/camera_info': []}
    bag = tmp_path / 'qos'
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, msgtype, log_time, raw in scene_messages(Scene(duration=0.3)):
            if topic not in offered:
                continue
            if topic not in connections:
                connections[topic] = writer.add_connection(
                    topic, msgtype, typestore=typestore(), offered_qos_profiles=offered[topic]
                )
            writer.write(connections[topic], log_time, raw)
    topics = read_recording(bag).topics
    assert topics['/scan'].qos == TopicQos(reliable=False, transient_local=False, depth=5)
    # tf2's listeners ask for transient local: /tf_static is latched whatever was recorded.
    assert topics['/tf_static'].qos == TopicQos(reliable=True, transient_local=True, depth=1)
    # Nothing recorded: ros2 bag's default, reliable and volatile.
    info = topics['/camera/depth/camera_info'].qos
    assert info == TopicQos(reliable=True, transient_local=False, depth=10)


def test_start_offset_skips_the_first_seconds_but_keeps_tf_static(tmp_path):
    scene = Scene(duration=2.0)
    bag = write_scene_bag(tmp_path / 'scene.mcap', scene)
    recording = read_recording(bag)
    counts = recorded_counts(bag)
    assert {name: topic.count for name, topic in recording.topics.items()} == counts
    played = list(recording.messages(list(recording.topics), start=1.0))
    by_topic: dict[str, int] = {}
    for message in played:
        by_topic[message.topic] = by_topic.get(message.topic, 0) + 1
    assert by_topic.get('/tf_static') == counts['/tf_static']
    # About half of the 2 s drive's scans (10 Hz) are left after 1 s.
    assert counts['/scan'] // 2 - 1 <= by_topic['/scan'] <= counts['/scan'] // 2 + 1
    offsets = [message.offset_ns for message in played]
    assert offsets == sorted(offsets)
    assert offsets[0] == 0


def test_unknown_topic_and_bad_options_say_what_to_do(tmp_path):
    bag = write_scene_bag(tmp_path / 'scene.mcap', Scene(duration=0.5))
    recording = read_recording(bag)
    with pytest.raises(BagError, match=r'/scann not in bag .*; its topics: .*/scan\b'):
        choose_topics(recording, ['/scann'])
    with pytest.raises(BagError, match='does not exist'):
        read_recording(tmp_path / 'missing.mcap')
    with pytest.raises(PlayError, match=r'--rate must be above 0 .* not 0'):
        PlayOptions(rate=0)
    with pytest.raises(PlayError, match='--start must be 0 or more'):
        PlayOptions(start=-1)
    empty = write_bag(tmp_path / 'empty.mcap', [])
    with pytest.raises(BagError, match='holds no messages'):
        read_recording(empty)


SUMMARY_LINE = re.compile(r'^\s+(/\S+)\s+(\d+) messages')


def summary(text: str) -> tuple[dict[str, int], dict[str, int]]:
    """(published, heard back) message counts per topic from `play`'s closing lines."""
    published: dict[str, int] = {}
    heard: dict[str, int] = {}
    target = published
    for line in text.splitlines():
        if line.startswith('heard back:'):
            target = heard
        elif match := SUMMARY_LINE.match(line):
            target[match.group(1)] = int(match.group(2))
    return published, heard


@pytest.mark.ros
def test_demo_commands_run_the_node_on_its_recording_over_dds(tmp_path):
    from scanfuse.sim.drive import scripted_path
    from scanfuse.sim.recording import record
    from scanfuse.sim.simulation import SimConfig

    # The demo's drive (app/demo.py), shorter and at a lower resolution.
    bag = tmp_path / 'bookshelf_drive.mcap'
    config = SimConfig(world='bookshelf', resolution=(424, 240), depth_rate=15.0)
    record(config, scripted_path('straight'), 3.0, bag)
    node_command, play_command = live_commands(bag)
    env = with_repository_on_path(
        {
            **os.environ,
            'ROS_DOMAIN_ID': str(domain_id()),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
    )
    node_log = (tmp_path / 'node.log').open('w')
    node = subprocess.Popen(
        shlex.split(node_command), env=env, stdout=node_log, stderr=subprocess.STDOUT
    )
    try:
        played = subprocess.run(
            # A fresh clone's node compiles its kernels first: wait for it as long as that takes.
            [*shlex.split(play_command), '--wait', '300'],
            env=env,
            capture_output=True,
            text=True,
            timeout=420,
            check=False,
        )
    finally:
        node.terminate()
        node.wait(timeout=30)
    node_output = (tmp_path / 'node.log').read_text(encoding='utf-8')
    assert played.returncode == 0, played.stderr + node_output
    published, heard = summary(played.stdout)
    counts = recorded_counts(bag)
    # Every recorded message went out once (a topic the drive never wrote to shows 0).
    assert {topic: count for topic, count in published.items() if count} == counts, played.stdout
    # The node answers each LiDAR scan with one fused scan (best effort may lose a few).
    assert 0.9 * counts['/scan'] <= heard['/scan_fused'] <= counts['/scan'], (
        played.stdout + node_output
    )
    assert re.search(r'/scan_fused\s+\d+ messages, [\d.]+ Hz, latency median', played.stdout)


def play_command(*args: str) -> list[str]:
    return [sys.executable, '-m', 'scanfuse', 'play', *args]


def test_a_ros1_bag_plays_every_message_of_the_chosen_topics(tmp_path):
    bag = write_scene_bag(tmp_path / 'scene.bag', Scene(duration=1.0), storage='ros1')
    counts = recorded_counts(bag)
    env = with_repository_on_path({**os.environ, 'ROS_DOMAIN_ID': str(domain_id())})
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    done = subprocess.run(
        play_command(str(bag), '--topic', '/scan', '--topic', '/tf_static', '--rate', '4'),
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    published, heard = summary(done.stdout)
    assert published == {'/scan': counts['/scan'], '/tf_static': counts['/tf_static']}
    assert heard == {}


@pytest.mark.ros
def test_loop_stops_cleanly_on_ctrl_c_with_its_summary_over_dds(tmp_path):
    import signal
    import time

    from rosbags.rosbag2 import Reader

    bag = write_scene_bag(tmp_path / 'scene.mcap', Scene(duration=1.0))
    counts = recorded_counts(bag)
    env = with_repository_on_path({**os.environ, 'ROS_DOMAIN_ID': str(domain_id())})
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONUNBUFFERED'] = '1'
    env['PYTHONFAULTHANDLER'] = '1'
    heard, ready, stop = tmp_path / 'heard.mcap', tmp_path / 'ready', tmp_path / 'stop'
    record = [sys.executable, '-m', 'tests.support.loopback', 'record', str(heard)]
    listener = subprocess.Popen(
        [
            *record,
            '--topic',
            '/scan',
            '--duration',
            '120',
            '--ready',
            str(ready),
            '--stop',
            str(stop),
        ],
        env=env,
    )
    player = None
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert ready.exists(), 'the listener did not start'
        player = subprocess.Popen(
            play_command(str(bag), '--loop', '--topic', '/scan', '--topic', '/tf_static'),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert player.stderr is not None
        first = player.stderr.readline()  # its console (stderr): "playing BAG ..., looping"
        assert first.startswith('playing'), first + player.stderr.read()
        # The 1 s recording, at its recorded pace: about six loops. DDS discovery on a loaded
        # machine can take seconds: the listener may miss the first loops.
        time.sleep(6.0)
        player.send_signal(signal.SIGINT)  # what Ctrl-C in its terminal sends
        try:
            out, err = player.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            # Where it hangs: PYTHONFAULTHANDLER prints every thread's Python stack on SIGABRT.
            player.send_signal(signal.SIGABRT)
            out, err = player.communicate(timeout=30)
            pytest.fail(f'play did not exit 30 s after Ctrl-C; its stderr:\n{err}')
    finally:
        if player is not None and player.poll() is None:
            player.kill()
        stop.write_text('stop', encoding='utf-8')
        listener.wait(timeout=60)
    assert player.returncode == 0, err
    assert 'Traceback' not in err
    assert 'stopped' in err  # its console (stderr); the summary is on stdout
    published, _ = summary(out)
    # More than one loop went out before Ctrl-C, and the summary counts every message sent.
    assert published['/scan'] > counts['/scan']
    with Reader(heard) as reader:
        received = sum(1 for _ in reader.messages())
    # Over DDS a listener got more than one loop's scans, and never more than were sent.
    assert counts['/scan'] < received <= published['/scan']


def test_the_first_ctrl_c_asks_play_to_stop_and_the_second_interrupts_it():
    stop = StopRequest()
    assert not stop.requested
    stop(2, None)  # SIGINT: the play loop reads the request between messages
    assert stop.requested
    with pytest.raises(KeyboardInterrupt):
        stop(2, None)
