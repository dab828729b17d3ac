"""examples/fastdds_announce.xml: the Fast DDS profile the README gives for a faster start.

Fast DDS matches a node that starts late with drivers either at once or at the drivers'
next announcement (every 3 s by default); the profile makes every participant announce
every 0.5 s. What it does to start-up is measured in `make bench` (bench_node); here, that
it says so and that the real Fast DDS of the wheels loads it (Jazzy's reads
FASTRTPS_DEFAULT_PROFILES_FILE, Kilted's FASTDDS_DEFAULT_PROFILES_FILE; both are set).
"""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros

PROFILE = Path(__file__).resolve().parents[2] / 'examples' / 'fastdds_announce.xml'
NAMESPACE = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def test_the_profile_is_every_participant_s_default_announcing_every_half_second():
    root = ET.parse(PROFILE).getroot()  # noqa: S314 - our own example file
    participant = root.find('p:participant', NAMESPACE)
    assert participant is not None
    assert participant.get('is_default_profile') == 'true'
    period = participant.find('p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement', NAMESPACE)
    assert period is not None
    seconds = int(period.findtext('p:sec', namespaces=NAMESPACE) or 0)
    nanoseconds = int(period.findtext('p:nanosec', namespaces=NAMESPACE) or 0)
    assert seconds + nanoseconds / 1e9 == 0.5


def start_a_node(profile: Path) -> tuple[int, str]:
    """A bare rclpy node started and stopped with `profile` as Fast DDS's profiles file: its
    exit code and what it printed (Fast DDS 2 logs to stdout, 3 to stderr)."""
    env = {
        **os.environ,
        'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile),
        'FASTDDS_DEFAULT_PROFILES_FILE': str(profile),
        'ROS_DOMAIN_ID': str(60 + os.getpid() % 20),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
    }
    code = (
        'import rclpy; rclpy.init(); node = rclpy.create_node("profile_check"); '
        'node.destroy_node(); rclpy.shutdown()'
    )
    done = subprocess.run(
        [sys.executable, '-c', code],
        check=False,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    return done.returncode, done.stdout + done.stderr


def test_fast_dds_loads_the_profile_without_a_parse_error(tmp_path):
    code, printed = start_a_node(PROFILE)
    assert code == 0, printed
    assert 'XMLPARSER' not in printed
    # The check can fail: Fast DDS reports a misspelt element of the same profile.
    misspelt = tmp_path / 'misspelt.xml'
    misspelt.write_text(
        PROFILE.read_text(encoding='utf-8').replace('leaseAnnouncement', 'leaseAnnouncment'),
        encoding='utf-8',
    )
    assert 'XMLPARSER' in start_a_node(misspelt)[1]
