"""Height-aware obstacle scan, against geometry ray-cast analytically in the test.

Scenes are axis-aligned boxes on a floor (base z = 0). The depth image is rendered
here: each pixel's ray (x_n, y_n, 1) in the optical frame is turned into the base
frame and intersected with the floor and the boxes; the depth Z along the optical
axis is that ray's parameter. Expected ranges are worked out by hand from the
scene (a face at x = 1.5 seen at angle theta is 1.5 / cos(theta) away).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse.camera import CameraModel
from scanfuse.convert.floor_fit import fit_floor
from scanfuse.convert.obstacle import ObstacleProjector, SlotLookup, obstacle_scan
from scanfuse.errors import InputError
from scanfuse.motion import PlanarMotion
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics

CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)
SMALL = CameraModel.from_intrinsics(160, 120, 131.25, 131.25, 80.0, 60.0)
INCREMENT = math.radians(0.5)
GRID = AngleGrid(-math.pi, INCREMENT, 720)  # [-pi, pi)
GRID_0_2PI = AngleGrid(0.0, INCREMENT, 720)  # [0, 2 pi)
GRID_CLOCKWISE = AngleGrid(math.pi, -INCREMENT, 720)  # pi down to -pi + increment
LIMITS = {
    'min_obstacle_height': 0.02,
    'max_obstacle_height': 0.5,
    'range_min': 0.2,
    'range_max': 10.0,
}

Box = tuple[float, float, float, float, float, float]  # x0, x1, y0, y1, z0, z1 in the base frame


def render(camera, extrinsics, boxes=(), *, floor=True, millimetres=True):
    """Depth along the optical axis of the nearest surface per pixel (0 / NaN: none)."""
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    optical = extrinsics.base_to_camera_optical
    rotation = optical.rotation_matrix
    origin = np.array(optical.translation)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1) @ rotation.T  # per unit depth
    depth = np.full(x_n.shape, np.inf)
    with np.errstate(divide='ignore', invalid='ignore'):
        if floor:
            at_floor = -origin[2] / rays[..., 2]
            depth = np.where(at_floor > 0, at_floor, depth)
        for box in boxes:
            low, high = np.array(box[0::2]), np.array(box[1::2])
            t_low = (low - origin) / rays
            t_high = (high - origin) / rays
            enter = np.nanmax(np.minimum(t_low, t_high), axis=-1)
            leave = np.nanmin(np.maximum(t_low, t_high), axis=-1)
            hit = (enter <= leave) & (enter > 0)
            depth = np.where(hit & (enter < depth), enter, depth)
    if millimetres:
        return np.where(depth < 60.0, np.round(depth * 1000.0), 0).astype(np.uint16)
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)


def nearest_angle(grid, index):
    """The angle of slot `index`'s interval closest to 0 (where a face x = const is nearest)."""
    centre = grid.angles()[index]
    centre = math.remainder(centre, 2 * math.pi)
    half = abs(grid.angle_increment) / 2
    return 0.0 if abs(centre) <= half else centre - math.copysign(half, centre)


def slot_at(grid, angle):
    return int(grid.slot_of(np.array([angle]))[0])


def projector(camera, extrinsics, grid=GRID, **changes):
    return ObstacleProjector(camera, extrinsics, grid, **{**LIMITS, **changes})


# -- the 5 cm box ---------------------------------------------------------------------------

BOX_5CM: Box = (1.5, 1.8, -0.2, 0.2, 0.0, 0.05)


@pytest.mark.parametrize('millimetres', [True, False])
def test_low_box_at_its_true_range(millimetres):
    extrinsics = Extrinsics.from_mounting(
        camera_height=0.4, camera_pitch=math.radians(20.0), lidar_height=0.2
    )
    depth = render(CAMERA, extrinsics, [BOX_5CM], millimetres=millimetres)
    scan = projector(CAMERA, extrinsics).scan(depth)
    half_width = math.atan(0.2 / 1.5)  # the front face spans |theta| <= 7.6 deg
    checked = 0
    for index, angle in enumerate(GRID.angles()):
        if abs(angle) + INCREMENT / 2 < half_width:
            expected = 1.5 / math.cos(nearest_angle(GRID, index))
            assert scan.ranges[index] == pytest.approx(expected, abs=0.01)
            checked += 1
        elif abs(angle) - INCREMENT / 2 > half_width and scan.ranges[index] == scan.ranges[index]:
            assert scan.ranges[index] == np.inf  # beside the box only floor: nothing
    assert checked >= 28
    assert scan.ranges[slot_at(GRID, 0.0)] == pytest.approx(1.5, abs=0.01)
    assert scan.frame_id == ''
    assert (scan.angle_min, scan.angle_increment, len(scan)) == (-math.pi, INCREMENT, 720)
    assert (scan.range_min, scan.range_max) == (0.2, 10.0)


def test_obstacle_scan_wrapper_matches_projector():
    extrinsics = Extrinsics.from_mounting(camera_height=0.4, camera_pitch=math.radians(20.0))
    depth = render(SMALL, extrinsics, [BOX_5CM])
    once = obstacle_scan(depth, SMALL, extrinsics, GRID, **LIMITS)
    np.testing.assert_array_equal(once.ranges, projector(SMALL, extrinsics).scan(depth).ranges)


# -- the floor is never an obstacle ---------------------------------------------------------


@pytest.mark.parametrize('pitch_deg', [0.0, 10.0, 20.0, 30.0, 45.0])
@pytest.mark.parametrize('roll_deg', [0.0, 5.0])
def test_flat_floor_is_free(pitch_deg, roll_deg):
    extrinsics = Extrinsics.from_mounting(
        camera_height=0.4, camera_pitch=math.radians(pitch_deg), camera_roll=math.radians(roll_deg)
    )
    scan = projector(CAMERA, extrinsics).scan(render(CAMERA, extrinsics))
    in_view = ~np.isnan(scan.ranges)
    assert in_view.sum() > 100  # about 70 deg of view: the test is not vacuous
    assert np.all(scan.ranges[in_view] == np.inf)


# -- the table top above the slab -----------------------------------------------------------

TABLE_TOP: Box = (1.0, 1.8, -0.5, 0.5, 0.68, 0.7)


def test_table_top_above_the_slab_is_not_reported():
    extrinsics = Extrinsics.from_mounting(camera_height=0.4, camera_pitch=math.radians(5.0))
    depth = render(CAMERA, extrinsics, [TABLE_TOP])
    scan = projector(CAMERA, extrinsics).scan(depth)
    in_view = ~np.isnan(scan.ranges)
    assert np.all(scan.ranges[in_view] == np.inf)
    # the same image with a slab reaching 0.8 m does report the table's edge at 1.0 m
    taller = projector(CAMERA, extrinsics, max_obstacle_height=0.8).scan(depth)
    assert taller.ranges[slot_at(GRID, 0.0)] == pytest.approx(1.0, abs=0.01)


# -- where the camera is not the LiDAR ------------------------------------------------------

WALL_2M: Box = (2.0, 2.2, -5.0, 5.0, 0.0, 2.0)


def test_off_centre_camera_range_is_from_the_lidar():
    extrinsics = Extrinsics.from_mounting(
        camera_x=0.10, camera_y=0.05, camera_height=0.3, lidar_height=0.2
    )
    scan = projector(CAMERA, extrinsics).scan(render(CAMERA, extrinsics, [WALL_2M]))
    # seen from the LiDAR at the origin the wall x = 2 is 2 / cos(theta) away (from the
    # camera it would be 1.9 / cos(theta'): 10 cm nearer)
    checked = 0
    for index, angle in enumerate(GRID.angles()):
        if abs(angle) < math.radians(28.0):
            assert scan.ranges[index] == pytest.approx(
                2.0 / math.cos(nearest_angle(GRID, index)), abs=0.01
            )
            checked += 1
        if abs(angle) > math.radians(45.0):
            assert np.isnan(scan.ranges[index])  # outside the camera's view
    assert checked > 100


@pytest.mark.parametrize('grid', [GRID, GRID_0_2PI, GRID_CLOCKWISE])
def test_backwards_camera_fills_slots_around_pi(grid):
    extrinsics = Extrinsics.from_mounting(
        camera_x=-0.2, camera_height=0.3, camera_yaw=math.pi, lidar_height=0.2
    )
    wall_behind: Box = (-2.2, -2.0, -5.0, 5.0, 0.0, 2.0)
    scan = projector(CAMERA, extrinsics, grid).scan(render(CAMERA, extrinsics, [wall_behind]))
    angles = grid.angles()
    behind = np.abs(np.mod(angles, 2 * math.pi) - math.pi) < math.radians(25.0)
    assert behind.sum() >= 99  # 49 slots either side of pi, and pi itself
    for index in np.flatnonzero(behind):
        # |cos| of the slot's angle closest to pi
        off_pi = abs(math.remainder(angles[index] - math.pi, 2 * math.pi))
        nearest = max(0.0, off_pi - INCREMENT / 2)
        assert scan.ranges[index] == pytest.approx(2.0 / math.cos(nearest), abs=0.01)
    ahead = np.abs(np.mod(angles + math.pi, 2 * math.pi) - math.pi) < math.radians(60.0)
    assert np.all(np.isnan(scan.ranges[ahead]))
    assert scan.ranges[slot_at(grid, math.pi)] == pytest.approx(2.0, abs=0.01)


# -- fragments of a revolution the camera cannot see (issue 12) -----------------------------

WALL_AHEAD: Box = (3.0, 3.2, -5.0, 5.0, 0.0, 2.0)
# Six 60-degree fragments of one turn (a fragmented scanner's messages), and the whole turn.
FRAGMENTS = [AngleGrid(-math.pi + k * math.pi / 3, INCREMENT, 120) for k in range(6)]
AHEAD_MOUNTING = {
    'camera_x': 0.1,
    'camera_height': 0.4,
    'camera_pitch': math.radians(20.0),
    'lidar_height': 0.2,
}


@pytest.mark.parametrize('millimetres', [True, False])
def test_fragments_out_of_view_take_no_pass_over_the_image(millimetres):
    # CAMERA sees atan(320 / 525) = 31.4 deg either side of ahead; seen from the LiDAR 0.1 m
    # behind it, a point ahead of the camera lies nearer the axis still. Of the six
    # fragments only [-60, 0) and [0, 60) deg can hold a point.
    extrinsics = Extrinsics.from_mounting(**AHEAD_MOUNTING)
    depth = render(CAMERA, extrinsics, [BOX_5CM, WALL_AHEAD], millimetres=millimetres)
    projectors = [projector(CAMERA, extrinsics, grid) for grid in FRAGMENTS]
    scans = [p.scan(depth) for p in projectors]
    assert [p.frames_converted for p in projectors] == [0, 0, 1, 1, 0, 0]
    assert [p.sees_grid for p in projectors] == [False, False, True, True, False, False]
    for p, scan in zip(projectors, scans, strict=True):
        if not p.sees_grid:
            assert np.isnan(scan.ranges).all()
            # What the skipped pass would have found: no point in any slot.
            assert np.isinf(p.nearest_squared(depth.ravel())).all()
            assert not p.drop_slots.any()
    # The box ahead at 1.5 m, in the fragment starting at 0 deg.
    assert scans[3].ranges[0] == pytest.approx(1.5, abs=0.01)
    whole = projector(CAMERA, extrinsics).scan(depth)
    assert np.isnan(whole.ranges[:240]).all()
    assert np.isnan(whole.ranges[480:]).all()


def test_a_moved_view_skips_a_fragment_only_while_no_point_can_reach_it():
    extrinsics = Extrinsics.from_mounting(**AHEAD_MOUNTING)
    depth = render(CAMERA, extrinsics, [BOX_5CM, WALL_AHEAD])

    def moved(degrees: float, tx: float = 0.0) -> PlanarMotion:
        turn = math.radians(degrees)
        return PlanarMotion(cos=math.cos(turn), sin=math.sin(turn), tx=tx)

    # [-120, -60) deg: the view ends at -31.4 deg. Turned 10 deg and moved 3 cm (a robot at
    # 1.5 rad/s and 0.5 m/s over 0.06 s) no point gets within 28 deg of it: no pass, NaN.
    beside = projector(CAMERA, extrinsics, FRAGMENTS[1])
    scan = beside.scan(depth, moved(-10.0, 0.03))
    assert beside.frames_converted == 0
    assert np.isnan(scan.ranges).all()
    # What the skipped pass would have found: no point in any slot.
    assert np.isinf(beside.nearest_squared(depth.ravel(), motion=moved(-10.0, 0.03))).all()
    # Turned -90 deg the box ahead (1.5 m at 0 deg) lands at -90 deg, inside the fragment:
    # the pass runs and finds it.
    scan = beside.scan(depth, moved(-90.0))
    assert beside.frames_converted == 1
    assert scan.ranges[60] == pytest.approx(1.5, abs=0.02)  # slot 60: -90 deg
    # A shift as long as the nearest point's reach could put a point at any bearing.
    behind = projector(CAMERA, extrinsics, FRAGMENTS[0])
    behind.scan(depth, moved(0.0, 5.0))
    assert behind.frames_converted == 1


def test_clockwise_grid_is_the_counter_clockwise_one_reversed():
    extrinsics = Extrinsics.from_mounting(camera_height=0.4, camera_pitch=math.radians(20.0))
    depth = render(CAMERA, extrinsics, [BOX_5CM, (3.0, 3.2, 0.5, 1.0, 0.0, 0.3)])
    forward = projector(CAMERA, extrinsics, GRID).scan(depth)
    clockwise = projector(CAMERA, extrinsics, GRID_CLOCKWISE).scan(depth)
    # clockwise slot k is at pi - k inc, which is counter-clockwise slot 720 - k (mod 720)
    reordered = forward.ranges[(720 - np.arange(720)) % 720]
    np.testing.assert_array_equal(clockwise.ranges, reordered)
    assert clockwise.ranges[360] == pytest.approx(1.5, abs=0.01)  # angle 0


def test_sideways_rolled_pitched_camera_sees_box_on_the_left():
    extrinsics = Extrinsics.from_mounting(
        camera_y=0.1,
        camera_height=0.4,
        camera_roll=math.radians(8.0),
        camera_pitch=math.radians(25.0),
        camera_yaw=math.pi / 2,
        lidar_height=0.2,
    )
    box_left: Box = (-0.2, 0.2, 1.5, 1.8, 0.0, 0.05)
    scan = projector(CAMERA, extrinsics).scan(render(CAMERA, extrinsics, [box_left]))
    assert scan.ranges[slot_at(GRID, math.pi / 2)] == pytest.approx(1.5, abs=0.01)
    finite = np.isfinite(scan.ranges)
    # every reported obstacle is on the box's face y = 1.5: range * sin(angle) = 1.5
    for index in np.flatnonzero(finite):
        low, high = GRID.angles()[index] + np.array([-0.5, 0.5]) * INCREMENT
        assert 1.5 / math.sin(high) - 0.01 <= scan.ranges[index] <= 1.5 / math.sin(low) + 0.01
    assert finite.sum() >= 28


def test_obstacle_nearer_than_range_min_is_minus_inf():
    # looking steeply down on a 30 cm block right in front of the LiDAR: 10 cm away
    extrinsics = Extrinsics.from_mounting(camera_height=0.6, camera_pitch=math.radians(80.0))
    block: Box = (0.1, 0.5, -0.3, 0.3, 0.0, 0.3)
    scan = projector(CAMERA, extrinsics).scan(render(CAMERA, extrinsics, [block]))
    assert scan.ranges[slot_at(GRID, 0.0)] == -np.inf


def test_no_valid_depth_gives_no_information():
    extrinsics = Extrinsics.from_mounting(camera_height=0.4, camera_pitch=math.radians(20.0))
    scanner = projector(SMALL, extrinsics)
    assert scanner.in_view.sum() > 100
    assert np.all(np.isnan(scanner.scan(np.zeros((120, 160), np.uint16)).ranges))
    assert np.all(np.isnan(scanner.scan(np.full((120, 160), np.nan, np.float32)).ranges))
    # depth only in the left half of the image: the right-hand slots stay NaN
    depth = render(SMALL, extrinsics)
    depth[:, 80:] = 0
    ranges = scanner.scan(depth).ranges
    assert np.all(np.isnan(ranges[GRID.angles() < math.radians(-10.0)]))
    assert np.all(ranges[(GRID.angles() > math.radians(10.0)) & scanner.in_view] == np.inf)


# -- the compiled kernel and the numpy reference --------------------------------------------


MOUNTINGS = [
    Extrinsics.from_mounting(camera_height=0.4, camera_pitch=math.radians(20.0)),
    Extrinsics.from_mounting(
        camera_x=0.1,
        camera_y=0.05,
        camera_height=0.3,
        camera_roll=0.1,
        camera_pitch=0.2,
        camera_yaw=3.0,
        lidar_x=-0.1,
        lidar_height=0.2,
        lidar_yaw=0.3,
    ),
]
PROJECTORS = [
    projector(SMALL, mounting, grid, range_min=0.0)
    for mounting in MOUNTINGS
    for grid in (GRID, GRID_CLOCKWISE, AngleGrid(-1.0, 0.01, 150))
]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(PROJECTORS),
    hnp.arrays(
        np.uint16,
        (120, 160),
        elements=st.sampled_from([0, 1, 150, 400, 999, 1500, 4000, 9000, 12000]),
    ),
    hnp.arrays(
        np.float32,
        (120, 160),
        elements=st.one_of(st.just(np.nan), st.floats(0.0, 12.0, width=32)),
    ),
)
def test_kernel_equals_numpy_reference(scanner, millimetres, metres):
    assert scanner.uses_kernel
    for depth in (millimetres.ravel(), metres.ravel()):
        kernel = scanner.nearest_squared(depth).copy()
        reference = scanner.nearest_squared(depth, reference=True).copy()
        np.testing.assert_array_equal(kernel, reference)


@given(
    st.floats(-10.0, 10.0),
    st.floats(-10.0, 10.0),
    st.sampled_from([GRID, GRID_CLOCKWISE, GRID_0_2PI, AngleGrid(-1.0, 0.01, 150)]),
)
def test_slot_lookup_agrees_with_atan2(x, y, grid):
    angle = math.atan2(y, x)
    offset = np.mod(angle - grid.angle_min, abs(grid.angle_increment)) / abs(grid.angle_increment)
    if math.hypot(x, y) < 1e-6 or abs(offset - 0.5) < 1e-6:  # exactly on a slot boundary
        return
    lookup = SlotLookup.for_grid(grid)
    slot = lookup.slots(np.array([x]), np.array([y]))[0]
    assert slot == grid.slot_of(np.array([angle]))[0]


def test_numpy_fallback_gives_the_same_scan():
    extrinsics = MOUNTINGS[1]
    depth = render(SMALL, extrinsics, [(-2.0, -1.5, -1.0, 1.0, 0.0, 0.3), BOX_5CM])
    compiled = projector(SMALL, extrinsics).scan(depth)
    plain = projector(SMALL, extrinsics, use_kernel=False)
    assert not plain.uses_kernel
    np.testing.assert_array_equal(plain.scan(depth).ranges, compiled.ranges)
    assert np.isfinite(compiled.ranges).sum() > 10


# -- errors ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('changes', 'match'),
    [
        ({'range_min': 5.0, 'range_max': 1.0}, 'range_min < range_max'),
        ({'range_min': -0.1}, 'range_min < range_max'),
        ({'min_obstacle_height': 0.5, 'max_obstacle_height': 0.1}, 'collision slab'),
        ({'range_max': math.inf}, 'range_max must be finite'),
    ],
)
def test_bad_limits(changes, match):
    extrinsics = Extrinsics.from_mounting(camera_height=0.4)
    with pytest.raises(InputError, match=match):
        projector(SMALL, extrinsics, **changes)


def test_wrong_image_size():
    scanner = projector(SMALL, Extrinsics.from_mounting(camera_height=0.4))
    with pytest.raises(InputError, match='use the CameraInfo that belongs to this image'):
        scanner.scan(np.zeros((480, 640), np.uint16))


# -- the real frame ------------------------------------------------------------------------


@pytest.mark.real_data
def test_real_frame_laptop_and_box_but_not_carpet(real_data):
    tifffile = pytest.importorskip('tifffile')
    depth = tifffile.imread(real_data / 'pcl_grabber' / 'frame_20121214T142255.814212_depth.tiff')
    fit = fit_floor(depth, CAMERA)
    extrinsics = Extrinsics.from_mounting(
        camera_height=fit.camera_height,
        camera_pitch=fit.camera_pitch,
        camera_roll=fit.camera_roll,
        lidar_height=0.2,
    )
    scan = projector(CAMERA, extrinsics, range_min=0.3, range_max=5.0).scan(depth)
    angles = np.degrees(GRID.angles())
    ranges = scan.ranges
    # The RGB image: a laptop (left of centre, columns 130-375) and a box (columns 375-505)
    # stand on the carpet; their bottom edges are near row 310, 70 px below the centre,
    # i.e. 45 + atan(70 / 525) = 52.6 deg below horizontal from 0.7 m up: 0.7 / tan(52.6 deg)
    # = 0.54 m ahead. Columns 130-505 are azimuths of about +20 to -25 deg.
    front = (angles > -20.0) & (angles < 18.0)
    assert np.all((ranges[front] > 0.45) & (ranges[front] < 0.7))
    # The image's left third and bottom right are only carpet: azimuths beyond +30 deg
    # and beyond -45 deg (bottom corners reach about +-57 deg) are free.
    in_view = ~np.isnan(ranges)
    carpet = in_view & ((angles > 30.0) | (angles < -45.0))
    assert carpet.sum() > 40
    assert np.all(ranges[carpet] == np.inf)
    # Overall: roughly a third of the view is free carpet, the rest laptop, box and clutter.
    free_share = float(np.mean(ranges[in_view] == np.inf))
    assert 0.25 < free_share < 0.6
