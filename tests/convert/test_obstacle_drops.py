"""Drop-offs (issue 15): ledges, pits and flat floors, ray-cast by hand.

The camera is at the base origin, 0.4 m above the floor, pitched 20 deg down; the LiDAR
0.3 m up at the base origin sees nothing (the floor and what is below it are under its
plane). A pixel with normalised coordinates (x_n, y_n) has the base-frame ray
(cos p - y_n sin p, -x_n, -(sin p + y_n cos p)) per unit of depth Z (the optical frame's
forward, left and up axes pitched down by p), so it meets a floor h below the camera at
Z = h / (sin p + y_n cos p), at x = Z (cos p - y_n sin p) ahead.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse import FusionConfig, FusionPipeline, Scan
from scanfuse.camera import CameraModel
from scanfuse.convert.obstacle import DropLimits, ObstacleProjector
from scanfuse.errors import ConfigError, InputError
from scanfuse.motion import PlanarMotion
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics

HEIGHT, PITCH = 0.4, math.radians(20.0)
CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
GRID = AngleGrid(-math.pi, 2.0 * math.pi / 1080, 1080)
EXTRINSICS = Extrinsics.from_mounting(camera_height=HEIGHT, camera_pitch=PITCH, lidar_height=0.3)
DEFAULTS = FusionConfig()
DEFAULT_DROPS = DropLimits(DEFAULTS.drop_min_depth, DEFAULTS.drop_min_width, DEFAULTS.depth_noise)


def rays(camera: CameraModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel the base-frame ray per unit depth: forward, left, down rates."""
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    forward = math.cos(PITCH) - y_n * math.sin(PITCH)
    down = math.sin(PITCH) + y_n * math.cos(PITCH)
    return forward, -x_n, down


def floor_depth(camera: CameraModel, below: float = HEIGHT) -> np.ndarray:
    """Depth of a floor `below` metres under the camera (NaN where the ray does not go down)."""
    _, _, down = rays(camera)
    with np.errstate(divide='ignore'):
        return np.where(down > 1e-9, below / down, np.nan)


def ledge_depth(camera: CameraModel, edge: float, drop: float) -> np.ndarray:
    """The floor ends at x = edge; beyond it, a lower floor `drop` metres down.

    A ray that meets the upper floor's plane beyond the edge passes above the edge
    (it is still above z = 0 at x = edge) and goes on to the lower floor.
    """
    forward, _, _ = rays(camera)
    upper = floor_depth(camera)
    return np.where(upper * forward < edge, upper, floor_depth(camera, HEIGHT + drop))


def trench_depth(camera: CameraModel, near: float, far: float, deep: float) -> np.ndarray:
    """A trench across the floor, near <= x <= far, `deep` metres deep, vertical walls.

    A ray entering it (meeting the floor's plane inside) ends on the far wall (x = far)
    or on the bottom, whichever is nearer.
    """
    forward, _, _ = rays(camera)
    upper = floor_depth(camera)
    x_at_floor = upper * forward
    inside = (x_at_floor >= near) & (x_at_floor <= far)
    with np.errstate(divide='ignore', invalid='ignore'):
        wall = far / forward
    bottom = floor_depth(camera, HEIGHT + deep)
    return np.where(inside, np.minimum(wall, bottom), upper)


def as_millimetres(depth: np.ndarray) -> np.ndarray:
    """16UC1: 0 where there is no reading or it is beyond 65.535 m (rays near the horizon)."""
    with np.errstate(invalid='ignore'):
        readable = np.isfinite(depth) & (depth < 65.5)
    return np.where(readable, np.round(depth * 1000.0), 0).astype(np.uint16)


def lidar_sees_nothing() -> Scan:
    return Scan(
        angle_min=GRID.angle_min,
        angle_max=GRID.angle_max,
        angle_increment=GRID.angle_increment,
        range_min=0.1,
        range_max=10.0,
        ranges=np.full(GRID.count, np.inf, np.float32),
        frame_id='laser',
    )


def config(**changes: object) -> FusionConfig:
    return FusionConfig(
        camera_x=0.0, camera_height=HEIGHT, camera_pitch=PITCH, lidar_height=0.3, **changes
    )


def projector(camera: CameraModel = CAMERA, **changes: object) -> ObstacleProjector:
    settings: dict[str, object] = {
        'min_obstacle_height': DEFAULTS.min_obstacle_height,
        'max_obstacle_height': DEFAULTS.max_obstacle_height,
        'range_min': DEFAULTS.range_min,
        'range_max': DEFAULTS.range_max,
        'min_points': DEFAULTS.obstacle_min_points,
        'cluster_spread': DEFAULTS.obstacle_cluster_spread,
        'drops': DEFAULT_DROPS,
        **changes,
    }
    return ObstacleProjector(camera, EXTRINSICS, GRID, **settings)  # type: ignore[arg-type]


# -- the hand-worked ledge --------------------------------------------------------------


@pytest.mark.parametrize('unit', ['metres', 'millimetres'])
def test_ledge_is_reported_at_its_edge(unit):
    # Floor ending 1.2 m ahead, a lower floor 0.5 m down. The slot at bearing theta meets
    # the edge x = 1.2 at 1.2 / cos(theta) from the LiDAR's origin (the base origin). The
    # nearest pixel beyond the edge crosses the floor plane within one image row of it:
    # rows are 1/525 rad apart, (x^2 + h^2) / h / 525 = 7.6 mm on the floor at 1.2 m. The
    # lower floor reads 0.9 / 0.4 = 2.25 times the upper floor's depth: far beyond the margin.
    depth = ledge_depth(CAMERA, edge=1.2, drop=0.5)
    image = as_millimetres(depth) if unit == 'millimetres' else depth.astype(np.float32)
    result = FusionPipeline(config()).fuse(lidar_sees_nothing(), image, CAMERA)
    angles = GRID.angles()
    ahead = np.abs(angles) < math.radians(30.0)
    edge = 1.2 / np.cos(angles[ahead])
    fused = result.fused.ranges[ahead].astype(np.float64)
    assert np.all(np.abs(fused - edge) < 0.03)
    assert np.all(fused >= edge - 1e-3)  # the crossing is beyond the edge: never nearer
    assert np.all(fused <= edge + 0.008)  # and within a row of it
    # The depth scan carries them as finite readings (what the memory keeps).
    assert np.all(np.isfinite(result.depth_scan.ranges[ahead]))
    # Without drops the ledge is invisible: nothing stands in the slab, the scan is free.
    blind = FusionPipeline(config(detect_drops=False)).fuse(lidar_sees_nothing(), image, CAMERA)
    assert np.all(blind.fused.ranges[ahead] == np.inf)


def test_ledge_drop_slots_and_the_floor_before_it():
    scanner = projector()
    depth = ledge_depth(CAMERA, edge=1.2, drop=0.5).astype(np.float32)
    scan = scanner.scan(depth)
    angles = GRID.angles()
    drops = scanner.drop_slots
    assert np.all(drops[np.abs(angles) < math.radians(30.0)])
    # Every drop slot is the edge: 1.2 / cos(theta) (within a row) in the slot's direction.
    edge = 1.2 / np.cos(angles[drops])
    assert np.all(np.abs(scan.ranges[drops] - edge) < 0.03)
    # The same floor without the ledge: no drop slot, a free scan.
    flat = scanner.scan(floor_depth(CAMERA).astype(np.float32))
    assert not scanner.drop_slots.any()
    assert np.all(np.isnan(flat.ranges) | (flat.ranges == np.inf))


def test_a_step_shallower_than_drop_min_depth_is_not_a_drop():
    # A 4 cm step down (below drop_min_depth = 5 cm): the robot drives over it. 8 cm: a drop.
    scanner = projector()
    scanner.scan(ledge_depth(CAMERA, edge=1.2, drop=0.04).astype(np.float32))
    assert not scanner.drop_slots.any()
    scanner.scan(ledge_depth(CAMERA, edge=1.2, drop=0.08).astype(np.float32))
    assert scanner.drop_slots[np.abs(GRID.angles()) < math.radians(30.0)].all()


# -- missing returns ---------------------------------------------------------------------


@pytest.mark.parametrize('missing', ['zero', 'nan', 'inf'])
def test_missing_returns_where_the_floor_should_be_are_not_drops(missing):
    # A black or shiny floor beyond 1.2 m: no return there (0 mm, NaN, REP-118 +Inf "too
    # far"). The camera loses a floor that way without any drop-off: no drop slot.
    forward, _, _ = rays(CAMERA)
    depth = floor_depth(CAMERA)
    lost = depth * forward >= 1.2
    if missing == 'zero':
        image = as_millimetres(depth)
        image[lost] = 0
    else:
        image = depth.astype(np.float32)
        image[lost] = np.nan if missing == 'nan' else np.inf
    scanner = projector()
    scan = scanner.scan(image)
    assert lost.sum() > 50_000
    assert not scanner.drop_slots.any()
    assert not np.isfinite(scan.ranges).any()


# -- a pit narrower than drop_min_width ----------------------------------------------------


def test_trench_narrower_than_drop_min_width_is_ignored():
    # A trench 0.15 m wide along the line of sight (0.70 <= x <= 0.85), 0.3 m deep. A ray
    # entering it at x0 ends on the far wall, (0.85 - x0) * 0.4 / x0 below the floor: more
    # than 5 cm for x0 < 0.85 * 0.4 / 0.45 = 0.756 m, so by default it is a drop at the
    # near edge, 0.7 / cos(theta). With drop_min_width = 0.2 m: no ray runs 0.2 m beyond
    # the edge inside it (0.15 / cos(theta) < 0.2 for |theta| < 41 deg), so it is ignored.
    depth = trench_depth(CAMERA, near=0.70, far=0.85, deep=0.3).astype(np.float32)
    angles = GRID.angles()
    ahead = np.abs(angles) < math.radians(25.0)
    scanner = projector()
    scan = scanner.scan(depth)
    assert scanner.drop_slots[ahead].all()
    assert np.all(np.abs(scan.ranges[ahead] - 0.7 / np.cos(angles[ahead])) < 0.03)
    wide_only = projector(drops=DropLimits(DEFAULTS.drop_min_depth, 0.2, DEFAULTS.depth_noise))
    ignored = wide_only.scan(depth)
    assert not wide_only.drop_slots.any()
    assert np.all(ignored.ranges[ahead] == np.inf)
    # A ledge is as wide as it gets: drop_min_width does not hide it.
    wide_only.scan(ledge_depth(CAMERA, edge=1.2, drop=0.5).astype(np.float32))
    assert wide_only.drop_slots[ahead].all()


# -- noise: flat floors never drop ---------------------------------------------------------


SMALL = CameraModel.from_intrinsics(80, 60, 42.2, 42.2, 39.5, 29.5)  # 87 deg across


@pytest.mark.parametrize('min_points', [DEFAULTS.obstacle_min_points, 1])
def test_flat_floor_with_default_noise_gives_no_drop_in_10000_frames(min_points):
    # Depth of the floor plus Gaussian noise sigma = 0.01 Z^2 (depth_noise), seeded. A drop
    # pixel needs its reading max(0.05 / -a_z, 6 sigma) behind the floor, -a_z = 0.4 / Z the
    # height lost per unit depth: 0.125 Z = 12.5 / Z sigma, 31 sigma at the image's bottom
    # (0.4 m), down to 6 sigma from 2.08 m to 3 m (range_max). Summing the Gaussian tail over
    # the 3120 floor pixels: 0.002 drop pixels expected in all 3.1e7 readings, so none even
    # with min_points = 1; with 16 (the default), 16 would have to share a slot in one frame.
    scanner = projector(SMALL, min_points=min_points)
    rng = np.random.default_rng(15)
    floor = floor_depth(SMALL).astype(np.float32)
    seen_floor = np.isfinite(floor) & (floor <= DEFAULTS.range_max)
    sigma = (DEFAULTS.depth_noise * floor**2).astype(np.float32)
    drop_slots = 0
    deepest = 0.0
    for _ in range(10):
        noise = rng.standard_normal((1000, *floor.shape), dtype=np.float32)
        frames = floor + sigma * noise
        deepest = max(deepest, float(noise[:, seen_floor].max()))
        for frame in frames:
            scanner.scan(frame)
            drop_slots += int(scanner.drop_slots.sum())
    assert drop_slots == 0
    assert seen_floor.sum() > 3000  # 3.1e7 noisy floor readings in all
    assert deepest > 4.5  # the noise did reach far behind the floor


# -- kernel = numpy reference, motion ------------------------------------------------------


@pytest.mark.parametrize('threads', [1, 2])
@pytest.mark.parametrize('unit', ['metres', 'millimetres'])
def test_kernel_equals_reference_with_drops_and_motion(threads, unit):
    rng = np.random.default_rng(4)
    depth = ledge_depth(CAMERA, edge=1.2, drop=0.3)
    depth[100:200, 300:400] = 1.0  # something standing in the slab too
    depth = depth + DEFAULTS.depth_noise * depth**2 * rng.standard_normal(depth.shape)
    image = as_millimetres(depth) if unit == 'millimetres' else depth.astype(np.float32)
    flat = image.ravel()
    scanner = projector(threads=threads)
    motions = [
        PlanarMotion(),
        PlanarMotion(tx=-0.1),
        PlanarMotion(cos=math.cos(0.05), sin=math.sin(0.05), tx=0.03, ty=-0.02),
    ]
    for motion in motions:
        kernel = scanner.nearest_squared(flat, motion=motion).copy()
        kernel_drops = scanner.drop_slots
        reference = scanner.nearest_squared(flat, reference=True, motion=motion).copy()
        np.testing.assert_array_equal(kernel, reference)
        np.testing.assert_array_equal(kernel_drops, scanner.drop_slots)
        assert kernel_drops.sum() > 50


def test_motion_moves_the_drop_edge():
    # The robot drove 0.1 m forward between the image and the scan: the edge, 1.2 m ahead
    # at the image's stamp, is 1.1 m ahead at the scan's.
    scanner = projector()
    depth = ledge_depth(CAMERA, edge=1.2, drop=0.5).astype(np.float32)
    scan = scanner.scan(depth, PlanarMotion(tx=-0.1))
    angles = GRID.angles()
    ahead = np.abs(angles) < math.radians(20.0)
    assert scanner.drop_slots[ahead].all()
    np.testing.assert_allclose(scan.ranges[ahead], 1.1 / np.cos(angles[ahead]), atol=0.03)


# -- parameters ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('values', 'match'),
    [
        ((0.0, 0.0, 0.01), 'drop_min_depth must be positive'),
        ((math.inf, 0.0, 0.01), 'drop_min_depth must be positive'),
        ((0.05, -0.1, 0.01), 'drop_min_width must be finite and at least 0'),
        ((0.05, 0.0, math.nan), 'depth_noise must be finite and at least 0'),
    ],
)
def test_bad_drop_limits(values, match):
    with pytest.raises(InputError, match=match):
        DropLimits(*values)


@pytest.mark.parametrize(
    ('values', 'match'),
    [
        ({'drop_min_depth': 0.0}, 'drop_min_depth: Input should be greater than 0'),
        ({'drop_min_width': -0.01}, 'drop_min_width: Input should be greater than or equal'),
        ({'depth_noise': 2.0}, 'depth_noise: Input should be less than or equal to 1'),
    ],
)
def test_bad_drop_parameters_are_refused_by_the_config(values, match):
    with pytest.raises(ConfigError, match=match):
        FusionConfig.from_dict(values)


def test_detect_drops_is_on_by_default():
    assert FusionConfig().detect_drops
