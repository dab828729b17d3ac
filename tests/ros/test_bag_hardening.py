"""Regression tests of issue 26 through `scanfuse bag` (the CLI on bags written into
tmp_path, as tests/ros/test_bag.py does)."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import yaml
from rosbags.highlevel import AnyReader

from scanfuse.cli import main
from scanfuse.ros.messages import LASER_SCAN, scan_from_msg, scan_to_cdr, typestore
from tests.support.synthetic import Scene, scene_messages, write_bag


def params_file(tmp_path, **values):
    path = tmp_path / 'params.yaml'
    path.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}), encoding='utf-8')
    return path


def read_scans(path, topic):
    store = typestore()
    with AnyReader([path]) as reader:
        wanted = [c for c in reader.connections if c.topic == topic]
        return [
            scan_from_msg(store.deserialize_cdr(raw, LASER_SCAN))
            for _, _, raw in reader.messages(connections=wanted)
        ]


def test_odd_scans_are_listed_as_malformed_and_every_other_scan_is_fused(tmp_path, capsys):
    """Issue 26.7: a scan with angle_min -1e12 (here the last, released by the end-of-bag
    flush), a denormal increment and a NaN time_increment, with full_circle: ValueError or
    OverflowError from the stream, and `scanfuse bag` discarded the whole output. Now each is
    skipped and listed; every other scan is fused onto the 360-degree grid."""
    store = typestore()
    messages = scene_messages(Scene(duration=1.0))
    scans = [i for i, (topic, *_) in enumerate(messages) if topic == '/scan']
    odd = {
        scans[3]: {'angle_increment': 1e-40},  # a float32 denormal
        scans[6]: {'time_increment': math.nan},
        scans[-1]: {'angle_min': -1e12},
    }
    for index, changes in odd.items():
        topic, msgtype, log_time, raw = messages[index]
        scan = replace(scan_from_msg(store.deserialize_cdr(raw, LASER_SCAN)), **changes)
        messages[index] = (topic, msgtype, log_time, scan_to_cdr(scan, store))
    source = write_bag(tmp_path / 'in', messages)
    params = params_file(tmp_path, full_circle=True, use_tf=True)
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 0
    assert re.search(r'malformed messages skipped\W+3\b', capsys.readouterr().out)
    fused = read_scans(tmp_path / 'out', '/scan_fused')
    assert len(fused) == len(scans) - len(odd)
    increment = fused[0].angle_increment
    assert all(len(scan) == math.floor(2 * math.pi / increment + 1e-9) for scan in fused)
    assert all(np.isfinite(scan.ranges).any() for scan in fused)
