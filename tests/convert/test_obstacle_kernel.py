"""The compiled obstacle kernel: motion, threads, hostile inputs, table limits, its cache.

Scenes are ray-cast by hand as in test_obstacle.py (its `render`). Expected slots come
from angles worked out here with `AngleGrid.slot_of`, ranges from the boxes' geometry.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse.config import FusionConfig
from scanfuse.convert.obstacle import FINEST_INCREMENT, SlotLookup
from scanfuse.errors import ConfigError, InputError
from scanfuse.motion import PlanarMotion
from scanfuse.pipeline import FusionPipeline
from scanfuse.scan import AngleGrid
from tests.convert.test_obstacle import (
    BOX_5CM,
    CAMERA,
    GRID,
    GRID_0_2PI,
    GRID_CLOCKWISE,
    INCREMENT,
    MOUNTINGS,
    SMALL,
    nearest_angle,
    projector,
    render,
    slot_at,
)
from tests.support import REPOSITORY

SRC = REPOSITORY / 'src'


def rotation(angle: float) -> PlanarMotion:
    return PlanarMotion(cos=math.cos(angle), sin=math.sin(angle))


# -- motion compensation --------------------------------------------------------------------


@pytest.mark.parametrize(
    ('grid', 'whole_slots'), [(GRID, 7), (GRID_CLOCKWISE, 7), (GRID_0_2PI, -30), (GRID, 0)]
)
def test_rotation_by_whole_slots_shifts_the_scan(grid, whole_slots):
    # The camera straight above the LiDAR: turning the points by k increments about the
    # LiDAR's origin turns the 5 cm box's face x = 1.5 (|theta| <= atan(0.2 / 1.5)) by as
    # much, so slot i's reading moves to the slot of angle(i) + k increments.
    extrinsics = MOUNTINGS[0]
    depth = render(CAMERA, extrinsics, [BOX_5CM])
    scanner = projector(CAMERA, extrinsics, grid, min_points=1)
    turn = whole_slots * INCREMENT
    still = scanner.scan(depth)
    moved = scanner.scan(depth, rotation(turn))
    angles = grid.angles()
    half_width = math.atan(0.2 / 1.5)
    checked = 0
    for index, angle in enumerate(angles):
        centre = math.remainder(angle, 2 * math.pi)
        if abs(centre) + INCREMENT / 2 < half_width:
            target = slot_at(grid, centre + turn)
            expected = 1.5 / math.cos(nearest_angle(grid, index))
            assert moved.ranges[target] == pytest.approx(expected, abs=0.01)
            assert moved.ranges[target] == pytest.approx(still.ranges[index], abs=0.005)
            checked += 1
    assert checked >= 28
    # What the camera covers turns with it: slot for slot, the NaN (unseen) pattern moves.
    shift = slot_at(grid, turn) - slot_at(grid, 0.0)
    np.testing.assert_array_equal(np.isnan(moved.ranges), np.roll(np.isnan(still.ranges), shift))
    if whole_slots == 0:
        np.testing.assert_array_equal(moved.ranges, still.ranges)


def test_translation_moves_the_range():
    # Moving the points 0.3 m towards the LiDAR (tx = -0.3): the face x = 1.5 is at x = 1.2.
    extrinsics = MOUNTINGS[0]
    depth = render(CAMERA, extrinsics, [BOX_5CM])
    moved = projector(CAMERA, extrinsics, min_points=1).scan(depth, PlanarMotion(tx=-0.3))
    assert moved.ranges[slot_at(GRID, 0.0)] == pytest.approx(1.2, abs=0.01)


MOTIONS = st.builds(
    lambda angle, tx, ty: PlanarMotion(cos=math.cos(angle), sin=math.sin(angle), tx=tx, ty=ty),
    st.floats(-math.pi, math.pi),
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
)
SCANNERS = [
    projector(SMALL, mounting, grid, range_min=0.0, min_points=k, cluster_spread=spread)
    for mounting in MOUNTINGS
    for grid in (GRID, GRID_CLOCKWISE, AngleGrid(-1.0, 0.01, 150))
    for k, spread in ((1, math.inf), (5, 0.05))
]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(SCANNERS),
    MOTIONS,
    hnp.arrays(
        np.uint16, (120, 160), elements=st.sampled_from([0, 1, 150, 400, 999, 1500, 4000, 9000])
    ),
    hnp.arrays(
        np.float32, (120, 160), elements=st.one_of(st.just(np.nan), st.floats(0.0, 12.0, width=32))
    ),
)
def test_moved_kernel_equals_numpy_reference(scanner, motion, millimetres, metres):
    for depth in (millimetres.ravel(), metres.ravel()):
        kernel = scanner.nearest_squared(depth, motion=motion).copy()
        reference = scanner.nearest_squared(depth, reference=True, motion=motion).copy()
        np.testing.assert_array_equal(kernel, reference)


# -- two threads ----------------------------------------------------------------------------


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(MOUNTINGS),
    st.one_of(st.just(PlanarMotion()), MOTIONS),
    hnp.arrays(np.uint16, (120, 160), elements=st.integers(0, 6000)),
)
def test_two_threads_give_the_same_scan(mounting, motion, depth):
    one = projector(SMALL, mounting, min_points=4, cluster_spread=0.05)
    two = projector(SMALL, mounting, min_points=4, cluster_spread=0.05, threads=2)
    assert two.threads == 2
    np.testing.assert_array_equal(two.scan(depth, motion).ranges, one.scan(depth, motion).ranges)
    with_box = render(SMALL, mounting, [BOX_5CM])
    np.testing.assert_array_equal(two.scan(with_box).ranges, one.scan(with_box).ranges)


@pytest.mark.parametrize('threads', [0, 65])
def test_config_bounds_obstacle_threads(threads):
    with pytest.raises(ConfigError, match='obstacle_threads'):
        FusionConfig().with_changes(obstacle_threads=threads)


def test_pipeline_passes_obstacle_threads():
    config = FusionConfig(obstacle_threads=2)
    built = FusionPipeline(config)._projector(SMALL, MOUNTINGS[0], GRID)
    assert built.threads == 2


@pytest.mark.parametrize('threads', [0, 65])
def test_thread_count_is_bounded(threads):
    with pytest.raises(InputError, match='threads must be 1 to 64'):
        projector(SMALL, MOUNTINGS[0], threads=threads)


# -- hostile inputs -------------------------------------------------------------------------

_OVERFLOW_SCRIPT = textwrap.dedent(
    """
    import math
    import numpy as np
    from scanfuse.camera import CameraModel
    from scanfuse.convert.obstacle import ObstacleProjector
    from scanfuse.errors import ScanfuseError
    from scanfuse.motion import PlanarMotion
    from scanfuse.scan import AngleGrid
    from scanfuse.transforms import Extrinsics

    camera = CameraModel.from_intrinsics(160, 120, 131.25, 131.25, 80.0, 60.0)
    grid = AngleGrid(-math.pi, math.radians(0.5), 720)
    limits = dict(min_obstacle_height=0.02, max_obstacle_height=0.5, range_min=0.2,
                  range_max=10.0, min_points=4, cluster_spread=0.05)
    images = [np.full((120, 160), 1500, np.uint16), np.full((120, 160), 1.5, np.float32)]
    level = dict(camera_height=0.3, lidar_height=0.2, camera_pitch=0.3)
    grids = [AngleGrid(-math.pi, 2 * math.pi / count, count) for count in (90, 360, 720, 1440)]
    grids += [AngleGrid(start, 0.01, count) for start in (-1.0, 0.0) for count in (150, 2000)]
    outcomes = []
    # finite in float64, infinite in the kernel's float32: the slot index of such a point
    # was NaN -> int, out of bounds (this sweep segfaulted before)
    for mounting in (dict(camera_x=1e39), dict(camera_x=1e39, camera_y=1e39),
                     dict(camera_x=-1e39, camera_y=1e39)):
        try:
            for lidar in grids:
                scanner = ObstacleProjector(
                    camera, Extrinsics.from_mounting(**level, **mounting), lidar, **limits
                )
                for depth in images:
                    assert len(scanner.scan(depth).ranges) == lidar.count
            outcomes.append('scan')
        except ScanfuseError:
            outcomes.append('refused')
    scanners = [ObstacleProjector(camera, Extrinsics.from_mounting(**level), grid, **limits,
                                  threads=threads) for threads in (1, 2)]
    for motion in (PlanarMotion(tx=1e39), PlanarMotion(ty=-1e39), PlanarMotion(cos=1e39, sin=1e39),
                   PlanarMotion(tx=math.inf), PlanarMotion(cos=math.nan, sin=math.nan)):
        try:
            for scanner in scanners:
                for depth in images:
                    ranges = scanner.scan(depth, motion).ranges
                    assert len(ranges) == 720
                    assert not np.isfinite(ranges).any()  # every point dropped: none is a range
            outcomes.append('scan')
        except ScanfuseError:
            outcomes.append('refused')
    print(' '.join(outcomes))
    """
)


def _run_python(script: str, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, **env}
    environment['PYTHONPATH'] = os.pathsep.join(
        [str(SRC), *filter(None, [os.environ.get('PYTHONPATH')])]
    )
    return subprocess.run(
        [sys.executable, '-c', script],
        capture_output=True,
        text=True,
        check=False,
        env=environment,
        timeout=600,
    )


def test_float32_overflowing_translation_does_not_crash():
    # In a subprocess: a segfault fails this test (return code -11) instead of pytest.
    done = _run_python(_OVERFLOW_SCRIPT)
    assert done.returncode == 0, done.stderr
    mountings, motions = done.stdout.split()[:3], done.stdout.split()[3:]
    assert set(mountings) <= {'scan', 'refused'}
    # 1e39 is finite: the kernel drops the points it overflows; inf and NaN are refused
    assert motions == ['scan', 'scan', 'scan', 'refused', 'refused']


@pytest.mark.parametrize(
    ('depth', 'match'),
    [
        (np.zeros(100, np.uint16), 'flattened image: 19200 uint16 or float32 values'),
        (np.zeros((120, 160), np.uint16), 'got shape \\(120, 160\\)'),
        (np.zeros(19200, np.float64), 'of float64'),
    ],
)
def test_nearest_squared_refuses_what_it_would_misread(depth, match):
    scanner = projector(SMALL, MOUNTINGS[0])
    with pytest.raises(InputError, match=match):
        scanner.nearest_squared(depth)


# -- the slot lookup's size -----------------------------------------------------------------


@pytest.mark.parametrize('increment', [1e-6, -1e-9, 5e-5])
def test_absurdly_fine_grid_is_refused(increment):
    # 100 readings 1e-6 rad apart asked for 16e6 lookup bins (1.6 GB, 5 s); 1e-9, 119 GiB.
    grid = AngleGrid(0.0, increment, 100)
    with pytest.raises(InputError, match='finer than the finest supported'):
        SlotLookup.for_grid(grid)
    with pytest.raises(InputError, match='readings per turn'):
        projector(SMALL, MOUNTINGS[0], grid)


def test_finest_supported_grid_still_works():
    # 0.0035 deg: 2^18 bins (7.3 MB); the slots of points at the readings' own angles.
    grid = AngleGrid(-0.002, FINEST_INCREMENT, 100)
    lookup = SlotLookup.for_grid(grid)
    assert lookup.first.size == 1 << 18
    angles = grid.angles()
    slots = lookup.slots(2.0 * np.cos(angles), 2.0 * np.sin(angles))
    np.testing.assert_array_equal(slots, np.arange(100))
    beyond = np.array([-0.002 - FINEST_INCREMENT, 0.5])
    assert np.all(lookup.slots(np.cos(beyond), np.sin(beyond)) == -1)


# -- start-up -------------------------------------------------------------------------------

_CACHE_SCRIPT = textwrap.dedent(
    """
    import math
    import numpy as np
    from scanfuse.camera import CameraModel
    from scanfuse.convert import obstacle_kernel
    from scanfuse.convert.obstacle import ObstacleProjector
    from scanfuse.scan import AngleGrid
    from scanfuse.transforms import Extrinsics

    camera = CameraModel.from_intrinsics(160, 120, 131.25, 131.25, 80.0, 60.0)
    scanner = ObstacleProjector(
        camera, Extrinsics.from_mounting(camera_height=0.4), AngleGrid(-math.pi, 0.01, 628),
        min_obstacle_height=0.02, max_obstacle_height=0.5, range_min=0.2, range_max=10.0,
        min_points=16, cluster_spread=0.02,
    )
    scanner.scan(np.full((120, 160), 1500, np.uint16))
    scanner.scan(np.full((120, 160), 1.5, np.float32))
    kernels = (obstacle_kernel.nearest_squared, obstacle_kernel.seen_slots)
    print(sum(sum(k.stats.cache_hits.values()) for k in kernels),
          sum(sum(k.stats.cache_misses.values()) for k in kernels))
    """
)


def test_second_start_loads_the_kernels_from_the_cache(tmp_path):
    # The first process compiles and writes the cache; the next one only loads it: a node
    # start pays no compilation on its first frame (nor in the constructor).
    cache = str(tmp_path / 'numba')
    first = _run_python(_CACHE_SCRIPT, NUMBA_CACHE_DIR=cache)
    assert first.returncode == 0, first.stderr
    second = _run_python(_CACHE_SCRIPT, NUMBA_CACHE_DIR=cache)
    assert second.returncode == 0, second.stderr
    hits, misses = (int(value) for value in second.stdout.split())
    assert misses == 0
    assert hits == 4  # two kernels, uint16 and float32 each
    assert any(Path(cache).rglob('*.nbi'))
