"""Shared fixtures: where the real recorded data lives; the node's kernels compiled once."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parent.parent


def _real_data_dir() -> Path:
    env = os.environ.get('SCANFUSE_REAL_DATA')
    return Path(env) if env else _REPO.parent / 'shared' / 'data' / 'real'


@pytest.fixture(scope='session')
def real_data() -> Path:
    """../shared/data/real (or $SCANFUSE_REAL_DATA); tests skip where it is absent."""
    path = _real_data_dir()
    if not path.is_dir():
        pytest.skip(f'real sensor data not found at {path} (set SCANFUSE_REAL_DATA)')
    return path


@pytest.fixture(scope='session', autouse=True)
def _compiled_kernels() -> None:
    """Compile (or load) the node's kernels once per test process, as the node's warm-up
    does: a node a test starts then loads them from numba's cache instead of compiling them
    (tens of seconds on a fresh clone) while the test replays a bag to it."""
    from scanfuse.config import FusionConfig
    from scanfuse.motion import PlanarPose
    from scanfuse.ros.live import LiveFusion
    from tests.support.synthetic import Scene, scene_messages

    live = LiveFusion(FusionConfig(use_tf=False))
    live.warm_up()
    # A second's replay with odometry: the memory's and scan matching's kernels too.
    for topic, _, log_time, raw in scene_messages(Scene(duration=1.0)):
        now = log_time / 1e9
        live.stream.add_odometry(log_time, PlanarPose(0.0, 0.0, 0.0))
        if topic == '/scan':
            live.on_scan(raw, now)
        elif topic == '/camera/depth/image_raw':
            live.on_depth(raw, now)
        elif topic == '/camera/depth/camera_info':
            live.on_camera_info(raw, now)
