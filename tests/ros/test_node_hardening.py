"""Regression tests of issue 26 through the node over DDS (see tests/ros/test_node_dds.py for
how the processes find each other)."""

from __future__ import annotations

import json

import pytest

from scanfuse.ros.messages import scan_from_cdr
from tests.ros.test_node_dds import BOX, SCENE_PARAMS, TOLERANCE, Loopback, ahead
from tests.support.synthetic import Scene, write_scene_bag

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros


@pytest.fixture
def loop_factory(tmp_path):
    made = []

    def make(**params):
        made.append(Loopback(tmp_path, params))
        return made[-1]

    yield make
    for item in made:
        item.close()


def test_memory_sizes_the_grid_cannot_hold_are_refused_at_run_time(tmp_path, loop_factory):
    """Issue 26.1: memory_radius 20 (in the old table's range) with the default memory_cell
    needed more cells than the grid holds and ended the node. Now the table stops at a
    radius the default cell allows, and a combination no grid holds is refused with a reason;
    the node keeps fusing."""
    scene = Scene(duration=3.0)
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    loop = loop_factory(use_tf=False, memory_radius=10.0, **SCENE_PARAMS)
    go = tmp_path / 'started'
    setters = {
        'radius': ('memory_radius', '20.0'),
        'cell': ('memory_cell', '0.005'),  # 10 m in 5 mm cells: 16 million cells
    }
    processes = {
        key: loop.loopback(
            key, 'set-param', name, value, '--out', str(tmp_path / f'{key}.json'), '--go', str(go)
        )
        for key, (name, value) in setters.items()
    }
    loop.record('/scan_fused')
    player = loop.play(bag, '--started', str(go))
    for key, process in processes.items():
        assert process.wait(timeout=60) == 0, loop.log(key)
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received()['/scan_fused']
    assert loop.node.poll() is None, loop.log('node')
    radius = json.loads((tmp_path / 'radius.json').read_text())
    cell = json.loads((tmp_path / 'cell.json').read_text())
    assert not radius['successful']
    assert 'memory_radius' in radius['reason']
    assert not cell['successful']
    assert 'memory_cell' in cell['reason']
    assert 'memory cells' in cell['reason']
    done = max(radius['done'], cell['done'])
    # The first scans may pass while the node still waits for the first CameraInfo.
    after = [
        ahead(scan)
        for t, raw in received
        if t > done + 0.15 and (scan := scan_from_cdr(raw)).stamp_ns >= scene.start_ns + 0.15e9
    ]
    assert after, 'the replay ended before the parameters were set'
    assert all(value == pytest.approx(BOX, abs=TOLERANCE) for value in after), after
