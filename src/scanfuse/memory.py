"""Obstacle memory: what the camera saw in the collision slab, kept in the odometry frame.

The depth camera sees about 87 degrees, the LiDAR 360; a low obstacle that leaves the
camera's view falls back to the LiDAR's reading, which passes over it. The memory keeps
the camera's obstacle points in the odometry frame and merges them into every output
scan, seen from the LiDAR at the scan's stamp. What it takes in (`FusionStream`): the
depth scan's reading of every slot (a camera's slab reading as the pixel of its frame that
stands for it, `nearest_pixels`: set on its slot's centre line, it could stand beside the
obstacle), and per depth frame every slab pixel no nearer than
its slot's reading (`slab_points`, `not_nearer_than`: a box's sides, its top back to the
far edge, not only the face nearest the LiDAR) that agrees with both its horizontal
neighbours (`agreement`: a pixel on a box's outline, or one that stereo noise threw back
along its ray, lands beside the box once seen from elsewhere), in cells that several
pixels fill (`add_dense`: stray floor noise inside the slab lies alone in its cell), the
mean of a cell's pixels (the noise averages out); of both, only
what the LiDAR does not see at its own height (`unseen_by`): the LiDAR sees that again
from anywhere, and a wall remembered on drifting odometry would stand in front of it.
The stream places every point with the odometry pose corrected by scan matching
(`scanfuse.scan_matching.DriftCorrection`, `memory_scan_matching`): "the odometry frame"
below is that corrected frame, which stays on the walls where wheel odometry drifts.

Store: a rolling grid of `cell` metre cells around the robot, one point per cell (the
newest seen there, its coordinates kept), so its size is bounded by construction:
(2 radius / cell)^2 cells. A point is forgotten when it is more than `radius` from the
robot, older than `max_age` (time the robot stood still not counted, if the stream says so:
`stand_still`), or when the camera looks at its place again and sees it
free. Only the camera clears: the LiDAR's plane passes over low obstacles by design.
Drawn into a scan, neighbouring cells are joined by the line between their points, and a
point on its own is a quarter cell wide (`_forget_and_project_loop`).

Clearing (per depth frame fused): the memory holds, for every place, what the camera saw
the last time it looked there. A remembered point whose whole slab column (a few heights:
the obstacle's own height is not kept) projects into the image within the camera's range,
its bottom onto a pixel with depth, none showing something nearer in front of it, has been
looked at:
it is forgotten, and what the camera sees there now (added right after) takes its place.
So a thing that went away is gone within one frame, noisy samples of one
surface never pile up (the nearest of many would be biased short), and a point hidden
behind a nearer obstacle, or partly outside the image (too close, below the view), is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.bearing import fast_atan2
from scanfuse.compiled import compiled
from scanfuse.config import MAX_MEMORY_CELLS, memory_grid_side
from scanfuse.distortion import distortion_coefficients
from scanfuse.errors import InputError
from scanfuse.motion import PlanarMotion
from scanfuse.scan import TWO_PI

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.convert.ground import GroundProfile, Lifts
    from scanfuse.motion import PlanarPose
    from scanfuse.scan import AngleGrid, Scan
    from scanfuse.transforms import Transform

    F64 = npt.NDArray[np.float64]

# How wide a remembered point is on its own, as a share of the cell: the gaps between
# neighbouring cells are drawn as lines (`_forget_and_project_loop`). Measured over the 60
# memory trials: 0.25 gave 0.64 % false obstacles and 0/60 collisions; no width (a point in
# its own slot only) 0.47 % but a collision and three goals fewer, 0.125 the same collision.
OWN_WIDTH = 0.25
# Cells kept at most: 2^21 (about 60 MB of arrays); a larger radius needs larger cells.
MAX_CELLS = MAX_MEMORY_CELLS
# Heights of the slab a remembered point is tried at, as fractions from bottom to top.
CLEAR_HEIGHTS = (0.1, 0.5, 0.9)
# How far beyond a point the depth must lie to count as seeing past it, metres at depth z:
# 5 cm, 2 % and three sigma of active-stereo noise (sigma about 0.01 z^2).
CLEAR_MARGIN = (0.05, 0.02, 0.03)


@dataclass(frozen=True)
class MemorySettings:
    radius: float = 2.0
    max_age: float = 20.0
    cell: float = 0.025

    def __post_init__(self) -> None:
        for name in ('radius', 'max_age', 'cell'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f'memory {name} must be a positive finite number, got {value}'
                raise InputError(msg)
        if self.side**2 > MAX_CELLS:
            msg = (
                f'memory_radius {self.radius} m with memory_cell {self.cell} m needs '
                f'{self.side**2} cells (at most {MAX_CELLS}); use a larger memory_cell'
            )
            raise InputError(msg)

    @property
    def side(self) -> int:
        """Cells along one side of the rolling grid (covers the radius with a margin)."""
        return memory_grid_side(self.radius, self.cell)


@dataclass(frozen=True)
class Placement:
    """A sensor's origin and xy axes in the odometry frame (a mirrored axis is allowed:
    an upside-down LiDAR's y axis points right)."""

    x: float
    y: float
    xx: float  # the sensor's x axis in odom
    xy: float
    yx: float  # the sensor's y axis in odom
    yy: float

    @classmethod
    def of(
        cls, base: PlanarPose, base_to_sensor: Transform, tilt: Transform | None = None
    ) -> Placement:
        """The sensor on a base at `base` (odom frame), mounted at `base_to_sensor`; on a
        base tilted by `tilt` (its roll and pitch: base to a level frame of its heading, an
        IMU's), its origin where it then stands: a LiDAR 0.3 m up a body pitched 7.1 degrees
        (a 1:8 ramp) stands 3.7 cm behind where it stands level: what the memory holds ahead
        lies that much farther from it, what it holds behind that much nearer. Its axes stay
        the mounting's: a scan is taken level.
        """
        pose = base.matrix() @ base_to_sensor.matrix
        origin = pose if tilt is None else base.matrix() @ tilt.matrix @ base_to_sensor.matrix
        return cls(
            float(origin[0, 3]),
            float(origin[1, 3]),
            float(pose[0, 0]),
            float(pose[1, 0]),
            float(pose[0, 1]),
            float(pose[1, 1]),
        )

    def to_odom(self, x: F64, y: F64) -> tuple[F64, F64]:
        """Sensor-frame points (x, y) in the odometry frame."""
        return self.x + self.xx * x + self.yx * y, self.y + self.xy * x + self.yy * y


def _forget_and_project_loop(
    keys: Any,
    xs: Any,
    ys: Any,
    seen_ns: Any,
    robot_x: float,
    robot_y: float,
    radius_squared: float,
    oldest_ns: int,
    ox: float,
    oy: float,
    xx: float,
    xy: float,
    yx: float,
    yy: float,
    angle_min: float,
    increment: float,
    count: int,
    turn: int,
    half_width: float,
    side: int,
    centres: Any,
    ranges: Any,
    unrolled: Any,
    out: Any,
) -> None:
    """One pass over the store: forget points beyond the radius or older than `oldest_ns`,
    and per slot keep the nearest of the others seen from a sensor at origin (ox, oy) with
    axes (xx, xy), (yx, yy) in odom (+Inf where none falls: no NaN inside, for fastmath).

    Each point fills the slots `half_width` either side of it covers; then every point and
    each remembered neighbour cell (east, north, north-east, north-west: each pair once)
    fill the slots between them at the nearer of their two ranges (a point whose four
    side neighbours are all remembered lies inside an area and draws none: seen from
    outside, the area's border is no farther than a cell behind). A surface kept as one
    point per cell is so drawn as the polyline through its points: no gaps between cells
    at any range, and no overhang past its ends (a point widened by half a cell either side
    hangs that far past a box's edge into the free slot beside it: a false obstacle).

    `unrolled` (3 `turn` values) is the turn laid out three times, so that a run of slots
    never wraps: each slot is a branch-free min, and the copies fold into `out` at the end.
    `centres` and `ranges` (one per cell) hold each point's slot coordinate and range.
    """
    unrolled[:] = np.inf
    scale = 1.0 / increment
    own_reach = half_width * abs(scale)
    widest = 0.5 * turn - 1.0  # a run never leaves the three copies
    for i in range(keys.size):
        ranges[i] = -1.0
        if keys[i] < 0:
            continue
        px = xs[i]
        py = ys[i]
        rx = px - robot_x
        ry = py - robot_y
        if rx * rx + ry * ry > radius_squared or seen_ns[i] < oldest_ns:
            keys[i] = -1
            continue
        dx = px - ox
        dy = py - oy
        x = xx * dx + xy * dy  # the axes are orthonormal: projections give coordinates
        y = yx * dx + yy * dy
        r = math.sqrt(x * x + y * y)
        if r == 0.0:
            continue
        # fast_atan2 is within 2e-4 rad: a slot boundary may shift that much.
        centre = (fast_atan2(y, x) - angle_min) * scale + 0.5
        if not 0.0 <= centre < turn:  # rare for a grid that starts near -pi
            centre -= turn * math.floor(centre / turn)
        centre += turn  # the middle copy
        centres[i] = centre
        ranges[i] = r
        reach = min(own_reach / r if r > half_width else abs(scale), widest)
        first = int(centre - reach)  # positive: int() is floor
        last = int(centre + reach)
        for slot in range(first, last + 1):
            unrolled[slot] = min(unrolled[slot], r)
    east = 1 << 31  # key steps: `ObstacleMemory._cells`
    for column in range(side):
        right = column + 1 if column + 1 < side else 0
        left = column - 1 if column > 0 else side - 1
        for row in range(side):
            i = column * side + row
            r = ranges[i]
            if r < 0.0:
                continue
            key = keys[i]
            up = row + 1 if row + 1 < side else 0
            down = row - 1 if row > 0 else side - 1
            if (
                keys[right * side + row] == key + east
                and keys[left * side + row] == key - east
                and keys[column * side + up] == key + 1
                and keys[column * side + down] == key - 1
            ):
                continue  # inside a remembered area: its border is nearer from outside
            centre = centres[i]
            for neighbour in range(4):
                if neighbour == 0:
                    j, step = right * side + row, east
                elif neighbour == 1:
                    j, step = column * side + up, 1
                elif neighbour == 2:
                    j, step = right * side + up, east + 1
                else:
                    j, step = left * side + up, 1 - east
                if ranges[j] < 0.0 or keys[j] != key + step:
                    continue
                other = centres[j] - centre
                if other > 0.5 * turn:
                    other -= turn
                elif other < -0.5 * turn:
                    other += turn
                first = int(centre + min(other, 0.0))
                last = int(centre + max(other, 0.0))
                nearer = min(r, ranges[j])
                for slot in range(first, last + 1):
                    unrolled[slot] = min(unrolled[slot], nearer)
    for slot in range(min(count, turn)):
        out[slot] = min(unrolled[slot], unrolled[slot + turn], unrolled[slot + 2 * turn])
    for slot in range(turn, count):  # a grid longer than a turn: the old kernel left these
        out[slot] = np.inf


_KERNEL = compiled(_forget_and_project_loop, fastmath=True)


class ObstacleMemory:
    """Remembered obstacle points in the odometry frame; see the module docstring."""

    def __init__(self, settings: MemorySettings | None = None) -> None:
        self.settings = settings or MemorySettings()
        side = self.settings.side
        self._x = np.zeros(side * side)
        self._y = np.zeros(side * side)
        self._seen_ns = np.zeros(side * side, dtype=np.int64)
        self._key = np.full(side * side, -1, dtype=np.int64)  # absolute cell, -1: empty
        # The projection's scratch (`_forget_and_project_loop`).
        self._unrolled = np.empty(0)
        self._centres = np.zeros(side * side)
        self._trig_grid: tuple[float, float, int] | None = None  # `add_scan`'s cos, sin
        self._trig = (np.zeros(0), np.zeros(0))
        self._ranges = np.zeros(side * side)
        self.cleared = 0
        # Time the robot stood still (`stand_still`): every stamp is taken on a clock that
        # stops then, so a point's age counts only the time the robot moved.
        self._still_ns = 0

    def __len__(self) -> int:
        return int(np.count_nonzero(self._key >= 0))

    def clear(self) -> None:
        self._key[:] = -1

    def stand_still(self, duration_ns: int) -> None:
        """The robot stood still for `duration_ns`: no remembered point ages meanwhile.

        Odometry's error, and so a remembered point's, grows as the robot moves, not as time
        passes; and a robot held beside a low obstacle out of the camera's view (its stop
        zone, a queue) would otherwise forget the obstacle after `max_age` and drive into it.
        """
        self._still_ns += max(0, int(duration_ns))

    def points(self) -> tuple[F64, F64]:
        """(x, y) in the odometry frame of every remembered point."""
        used = self._key >= 0
        return self._x[used].copy(), self._y[used].copy()

    # ------------------------------------------------------------ adding and forgetting

    def _cells(self, x: F64, y: F64) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        side, cell = self.settings.side, self.settings.cell
        i = np.floor(x / cell).astype(np.int64)
        j = np.floor(y / cell).astype(np.int64)
        # Non-negative for |cell index| < 2^30 (26 000 km at 2.5 cm): -1 stays "empty".
        key = (i + (1 << 30)) * (1 << 31) + (j + (1 << 30))
        return np.mod(i, side) * side + np.mod(j, side), key

    def _within(self, x: F64, y: F64, robot: tuple[float, float]) -> npt.NDArray[np.bool_]:
        """Finite points inside `radius` of the robot: the only ones the rolling grid holds
        apart (two cells `side` apart share a slot, so a point 4 m off would overwrite one
        behind the robot; it would be forgotten at the next scan anyway)."""
        with np.errstate(invalid='ignore'):
            near = np.hypot(x - robot[0], y - robot[1]) <= self.settings.radius
        return near & np.isfinite(x) & np.isfinite(y)

    def add(self, x: F64, y: F64, stamp_ns: int, *, robot: tuple[float, float]) -> None:
        """Remember points (odometry frame) seen at `stamp_ns` within `radius` of `robot`
        (odometry frame); one per cell, the newest."""
        keep = self._within(x, y, robot)
        x, y = x[keep], y[keep]
        index, key = self._cells(x, y)
        self._x[index] = x
        self._y[index] = y
        self._seen_ns[index] = stamp_ns - self._still_ns
        self._key[index] = key

    def clock(self, stamp_ns: int) -> int:
        """`stamp_ns` (now) on the memory's clock, which stops while the robot stands still
        (`stand_still`): what `move_since` takes."""
        return stamp_ns - self._still_ns

    def move_since(self, since: int, move: PlanarPose, until: int | None = None) -> int:
        """Move the points seen after `since` (the memory's `clock`; and at or before
        `until`) by `move` (p' = R p + t, odometry frame): they were placed on a frame that
        has since been corrected by that much (`DriftCorrection.anchored_since_ns`). One
        point per cell, the newest, as `add` keeps them: a moved point takes the cell it
        lands in unless that holds a newer one. Returns how many moved."""
        chosen = (self._key >= 0) & (self._seen_ns > since)
        if until is not None:
            chosen &= self._seen_ns <= until
        moved = np.flatnonzero(chosen)
        if not moved.size:
            return 0
        x, y, seen = self._x[moved], self._y[moved], self._seen_ns[moved]
        self._key[moved] = -1
        motion = PlanarMotion(math.cos(move.yaw), math.sin(move.yaw), move.x, move.y)
        x, y = motion.apply(x, y)
        index, key = self._cells(x, y)
        order = np.lexsort((-seen, index))  # per cell, the newest first
        first = order[np.r_[True, index[order][1:] != index[order][:-1]]]
        there = index[first]
        first = first[(self._key[there] < 0) | (self._seen_ns[there] <= seen[first])]
        self._x[index[first]] = x[first]
        self._y[index[first]] = y[first]
        self._seen_ns[index[first]] = seen[first]
        self._key[index[first]] = key[first]
        return int(moved.size)

    def add_scan(
        self,
        scan: Scan,
        sensor: Placement,
        stamp_ns: int,
        keep: npt.NDArray[np.bool_],
        *,
        robot: tuple[float, float],
    ) -> None:
        """Remember the finite in-range readings of `scan` whose `keep` is set, seen from
        `sensor` at `stamp_ns`, within `radius` of `robot` (what `add` does with their points,
        per reading in one compiled pass: it runs on every output scan)."""
        grid = (scan.angle_min, scan.angle_increment, len(scan))
        if self._trig_grid != grid:
            angles = scan.angles()
            self._trig = (np.cos(angles), np.sin(angles))
            self._trig_grid = grid
        _ADD_SCAN(
            scan.ranges,
            np.ascontiguousarray(keep),
            scan.range_min,
            scan.range_max,
            self._trig[0],
            self._trig[1],
            sensor.x,
            sensor.y,
            sensor.xx,
            sensor.xy,
            sensor.yx,
            sensor.yy,
            robot[0],
            robot[1],
            self.settings.radius**2,
            self.settings.cell,
            self.settings.side,
            stamp_ns - self._still_ns,
            self._key,
            self._x,
            self._y,
            self._seen_ns,
        )

    def add_dense(
        self, x: F64, y: F64, stamp_ns: int, *, min_count: int, robot: tuple[float, float]
    ) -> int:
        """Remember, for each cell that `min_count` or more of the points (odometry frame)
        within `radius` of `robot` fall in, the mean of its points; how many cells. Many
        pixels of one surface fill a cell, while a stray pixel of floor noise inside the slab
        lies alone in its cell; the mean of a cell's pixels is steadier than any one of them
        (stereo noise moves each along its own ray) and lies in the cell, on the surface's
        side of it. (Within the radius no two cells share a slot, so counting by slot is
        exact.)"""
        keep = self._within(x, y, robot)
        x, y = x[keep], y[keep]
        index, _ = self._cells(x, y)
        slots = self._key.size
        counts = np.bincount(index, minlength=slots)
        dense = np.flatnonzero(counts >= min_count)
        sum_x = np.bincount(index, weights=x, minlength=slots)[dense]
        sum_y = np.bincount(index, weights=y, minlength=slots)[dense]
        self.add(sum_x / counts[dense], sum_y / counts[dense], stamp_ns, robot=robot)
        return int(dense.size)

    def scan(
        self, sensor: Placement, grid: AngleGrid, *, robot: tuple[float, float], now_ns: int
    ) -> F64:
        """Forget points beyond `radius` from `robot` or older than `max_age` at `now_ns`;
        the ranges of the others per slot of `grid`, seen from `sensor` (NaN: none)."""
        out = np.empty(grid.count, dtype=np.float64)
        turn = round(TWO_PI / abs(grid.angle_increment))
        if self._unrolled.size != 3 * turn:
            self._unrolled = np.empty(3 * turn)
        _KERNEL(
            self._key,
            self._x,
            self._y,
            self._seen_ns,
            robot[0],
            robot[1],
            self.settings.radius**2,
            now_ns - self._still_ns - round(self.settings.max_age * 1e9),
            sensor.x,
            sensor.y,
            sensor.xx,
            sensor.xy,
            sensor.yx,
            sensor.yy,
            grid.angle_min,
            grid.angle_increment,
            grid.count,
            turn,
            OWN_WIDTH * self.settings.cell / 2.0,
            self.settings.side,
            self._centres,
            self._ranges,
            self._unrolled,
            out,
        )
        out[np.isinf(out)] = np.nan
        return out

    # ------------------------------------------------------------ clearing by the camera

    def clear_seen(
        self,
        depth: npt.NDArray[np.generic],
        camera: CameraModel,
        odom_to_optical: Transform,
        *,
        slab: tuple[float, float],
        range_min: float,
        range_max: float,
        profile: GroundProfile | None = None,
    ) -> int:
        """Forget the points the camera sees free in `depth`; how many were forgotten.

        `odom_to_optical` is the camera's optical frame in the odometry frame at the
        image's stamp; heights are above the odometry frame's z = 0 (the floor), and above
        the ground of `profile` (this frame's ramps) where there is one.
        """
        low, high = slab
        heights = np.array([low + (high - low) * f for f in CLEAR_HEIGHTS])
        coefficients, pixels, scale = lens_and_depth(camera, depth)
        cleared = _CLEAR(
            self._key,
            self._x,
            self._y,
            heights,
            odom_to_optical.rotation_matrix,
            np.asarray(odom_to_optical.translation),
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            coefficients,
            pixels,
            scale,
            range_min,
            range_max,
            np.asarray(CLEAR_MARGIN),
            *profile_arrays(profile),
        )
        self.cleared += cleared
        return int(cleared)


def lens_and_depth(
    camera: CameraModel, depth: npt.NDArray[np.generic]
) -> tuple[F64, npt.NDArray[Any], float]:
    """A camera's eight distortion coefficients (zeros: none) and `depth` as the kernels
    read it: contiguous, uint16 millimetres kept, anything else as float32 metres; and the
    metres per unit."""
    if camera.has_distortion:
        coefficients = distortion_coefficients(camera.distortion_model, camera.distortion)
    else:
        coefficients = np.zeros(8)
    image = np.ascontiguousarray(depth)
    if image.dtype == np.uint16:
        return coefficients, image, 1e-3
    return coefficients, image.astype(np.float32), 1.0


def profile_arrays(profile: GroundProfile | None) -> tuple[Any, ...]:
    """A profile's columns, heights, bin size and horizontal axes as `_clear_loop` takes
    them (no columns: no profile)."""
    if profile is None:
        return np.zeros(0, np.int64), np.zeros((0, 1)), 1.0, np.zeros(3), np.zeros(3)
    forward, left = profile.axes()
    return profile.columns, profile.heights, profile.bin_size, forward, left


def _ground_under(
    gx: float,
    gy: float,
    gz: float,
    fx: float,
    cx: float,
    columns: Any,
    profile: Any,
    bin_size: float,
    forward: Any,
    left: Any,
) -> float:
    """The profile's ground height under the floor point (gx, gy, gz) of the optical frame:
    its image column's profile, linear between bin centres (0 without a profile)."""
    if columns.size == 0 or not gz > 0.0:
        return 0.0
    step = columns[1] - columns[0] if columns.size > 1 else 1
    u = fx * gx / gz + cx
    c = min(max(round((u - columns[0]) / step), 0), min(columns.size, profile.shape[0]) - 1)
    along = forward[0] * gx + forward[1] * gy + forward[2] * gz
    across = left[0] * gx + left[1] * gy + left[2] * gz
    position = math.sqrt(along * along + across * across) / bin_size - 0.5
    bins = profile.shape[1]
    if not position > 0.0:
        return float(profile[c, 0])
    if not position < bins - 1:
        return float(profile[c, bins - 1])
    b = int(position)
    share = position - b
    return float(profile[c, b] + share * (profile[c, b + 1] - profile[c, b]))


def _pixel_of(
    ox: float, oy: float, z: float, fx: float, fy: float, cx: float, cy: float, d: Any
) -> tuple[int, int]:
    """The pixel (u, v) of the optical-frame point (ox, oy, z), z > 0, through the lens's
    distortion (`d`: `distortion_coefficients`' eight, zeros for none)."""
    xn = ox / z
    yn = oy / z
    r2 = xn * xn + yn * yn
    radial = (1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))) / (
        1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7]))
    )
    xd = xn * radial + 2.0 * d[2] * xn * yn + d[3] * (r2 + 2.0 * xn * xn)
    yd = yn * radial + d[2] * (r2 + 2.0 * yn * yn) + 2.0 * d[3] * xn * yn
    return round(fx * xd + cx), round(fy * yd + cy)


pixel_of = compiled(_pixel_of)


def _clear_loop(
    keys: Any,
    xs: Any,
    ys: Any,
    heights: Any,
    rotation: Any,
    origin: Any,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    d: Any,
    depth: Any,
    scale: float,
    range_min: float,
    range_max: float,
    margin: Any,
    profile_columns: Any,
    profile: Any,
    bin_size: float,
    forward: Any,
    left: Any,
) -> int:
    """`ObstacleMemory.clear_seen` one point at a time; the count of points forgotten.

    A point is looked at when every height of its slab column projects into the image
    within the range limits, its bottom onto a pixel with depth (higher ones may see out
    over nothing), and no pixel shows something in front of it (hidden: nearer than the
    point by more than the noise).
    """
    rows, columns = depth.shape
    cleared = 0
    for i in range(keys.size):
        if keys[i] < 0:
            continue
        looked_at = True
        wx = xs[i] - origin[0]
        wy = ys[i] - origin[1]
        # The ground under the point: the floor's, raised by a ramp's (`profile`).
        lift = ground_under(
            rotation[0, 0] * wx + rotation[1, 0] * wy - rotation[2, 0] * origin[2],
            rotation[0, 1] * wx + rotation[1, 1] * wy - rotation[2, 1] * origin[2],
            rotation[0, 2] * wx + rotation[1, 2] * wy - rotation[2, 2] * origin[2],
            fx, cx, profile_columns, profile, bin_size, forward, left,
        )  # fmt: skip
        for rank in range(heights.size):
            wz = heights[rank] + lift - origin[2]
            # optical = R^T (world - origin)
            ox = rotation[0, 0] * wx + rotation[1, 0] * wy + rotation[2, 0] * wz
            oy = rotation[0, 1] * wx + rotation[1, 1] * wy + rotation[2, 1] * wz
            z = rotation[0, 2] * wx + rotation[1, 2] * wy + rotation[2, 2] * wz
            if not range_min <= z <= range_max:
                looked_at = False
                break
            u, v = pixel_of(ox, oy, z, fx, fy, cx, cy, d)
            if not (0 <= u < columns and 0 <= v < rows):
                looked_at = False
                break
            measured = depth[v, u] * scale
            if not measured > 0.0:
                # No return: the bottom must be seen; higher up it may look out over nothing.
                if rank == 0:
                    looked_at = False
                    break
                continue
            if measured < z - margin[0] - margin[1] * z - margin[2] * z * z:  # hidden
                looked_at = False
                break
        if looked_at:
            keys[i] = -1
            cleared += 1
    return cleared


ground_under = compiled(_ground_under)
_CLEAR = compiled(_clear_loop)


def slab_points(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    odom_to_optical: Transform,
    *,
    slab: tuple[float, float],
    range_min: float,
    range_max: float,
    agreement: float = 0.0,
    lifts: Lifts | None = None,
    bottom_noise: float = 0.0,
) -> tuple[F64, F64]:
    """Every pixel of `depth` whose point lies in the collision slab, in the odometry frame.

    Depth along the optical axis within [range_min, range_max] (uint16 millimetres, 0 no
    return; float metres, NaN none), heights above the odometry frame's z = 0 within
    `slab`: the points the obstacle method bins by slot, before it keeps only the near
    cluster of each (the faces behind it, a box's far edge seen over its top, are here too).
    With `agreement` > 0, only pixels whose left and right neighbours' depths lie within
    that share of their own (a pixel of the image's first or last column has no two).
    `lifts` (`GroundProfile.slab_lifts`: its first two levels, the slab's top and bottom) raise the
    slab's top and bottom per pixel by the ground under them (a ramp), as the obstacle scan's;
    `bottom_noise` raises the bottom by that times |a_z| Z^2, a_z the height a pixel's point
    gains per metre of depth (`obstacle._depth_interval`'s).
    """
    if not (math.isfinite(agreement) and agreement >= 0.0):
        msg = f'slab_points agreement must be a share >= 0, got {agreement}'
        raise InputError(msg)
    image = np.ascontiguousarray(depth)
    metres = image.dtype != np.uint16
    pixels = image.astype(np.float32) if metres else image
    x_n, y_n = camera.normalized_coordinates
    out_x = np.empty(image.size)
    out_y = np.empty(image.size)
    found = _SLAB(
        pixels,
        1.0 if metres else 1e-3,
        x_n,
        y_n,
        odom_to_optical.rotation_matrix,
        np.asarray(odom_to_optical.translation, dtype=np.float64),
        slab[0],
        slab[1],
        np.zeros((2, 0, 0)) if lifts is None else lifts.coarse,
        1 if lifts is None else lifts.stride,
        range_min,
        range_max,
        agreement,
        bottom_noise,
        out_x,
        out_y,
    )
    return out_x[:found].copy(), out_y[:found].copy()


def _slab_loop(
    depth: Any,
    scale: float,
    x_n: Any,
    y_n: Any,
    rotation: Any,
    origin: Any,
    low: float,
    high: float,
    lifts: Any,
    stride: int,
    range_min: float,
    range_max: float,
    agreement: float,
    bottom_noise: float,
    out_x: Any,
    out_y: Any,
) -> int:
    """`slab_points` one pixel at a time: how many points it wrote to out_x, out_y.
    `lifts` (the slab's top and bottom raised, per block of `stride` pixels a side: levels x
    block rows x block columns, `ground.Lifts.coarse`; 0 rows: none)."""
    rows, columns = depth.shape
    lifted = (
        lifts.shape[0] >= 2
        and lifts.shape[1] * stride >= rows
        and lifts.shape[2] * stride >= columns
    )
    found = 0
    for v in range(rows):
        block_row = v // stride
        for u in range(columns):
            z = depth[v, u] * scale
            if not range_min <= z <= range_max:  # NaN and 0 (no return) fail too
                continue
            ox = x_n[v, u] * z
            oy = y_n[v, u] * z
            height = rotation[2, 0] * ox + rotation[2, 1] * oy + rotation[2, 2] * z + origin[2]
            if lifted:
                block = u // stride
                top, bottom = high + lifts[0, block_row, block], low + lifts[1, block_row, block]
            else:
                top, bottom = high, low
            if bottom_noise > 0.0:
                a_z = rotation[2, 0] * x_n[v, u] + rotation[2, 1] * y_n[v, u] + rotation[2, 2]
                bottom += bottom_noise * abs(a_z) * z * z
            if not bottom <= height <= top:
                continue
            if agreement > 0.0:
                if u == 0 or u == columns - 1:
                    continue
                apart = agreement * z  # NaN and 0 neighbours fail both tests
                if not (
                    abs(depth[v, u - 1] * scale - z) <= apart
                    and abs(depth[v, u + 1] * scale - z) <= apart
                ):
                    continue
            out_x[found] = (
                rotation[0, 0] * ox + rotation[0, 1] * oy + rotation[0, 2] * z + origin[0]
            )
            out_y[found] = (
                rotation[1, 0] * ox + rotation[1, 1] * oy + rotation[1, 2] * z + origin[1]
            )
            found += 1
    return found


def _add_scan_loop(
    ranges: Any,
    keep: Any,
    range_min: float,
    range_max: float,
    cos: Any,
    sin: Any,
    ox: float,
    oy: float,
    xx: float,
    xy: float,
    yx: float,
    yy: float,
    robot_x: float,
    robot_y: float,
    radius_squared: float,
    cell: float,
    side: int,
    stamp_ns: int,
    keys: Any,
    xs: Any,
    ys: Any,
    seen_ns: Any,
) -> None:
    """`ObstacleMemory.add_scan` one reading at a time (cells as `ObstacleMemory._cells`)."""
    for k in range(ranges.size):
        r = ranges[k]
        if not keep[k] or not range_min <= r <= range_max:
            continue
        sx = r * cos[k]
        sy = r * sin[k]
        x = ox + xx * sx + yx * sy
        y = oy + xy * sx + yy * sy
        if not (math.isfinite(x) and math.isfinite(y)):  # `add` drops them too
            continue
        if (x - robot_x) ** 2 + (y - robot_y) ** 2 > radius_squared:  # as `add`: `_within`
            continue
        i = math.floor(x / cell)
        j = math.floor(y / cell)
        index = (i % side) * side + (j % side)  # Python's modulo: never negative
        xs[index] = x
        ys[index] = y
        seen_ns[index] = stamp_ns
        keys[index] = (i + (1 << 30)) * (1 << 31) + (j + (1 << 30))


_ADD_SCAN = compiled(_add_scan_loop)


def lidar_misses(
    depth_scan: Scan, lidar: Scan, margin: tuple[float, float]
) -> npt.NDArray[np.bool_]:
    """Per slot of two scans on one grid: the LiDAR does not see the depth scan's reading
    (`unseen_by` for points that lie in their own slot)."""
    reading = lidar.ranges.astype(np.float64)
    reach = depth_scan.ranges.astype(np.float64)
    with np.errstate(invalid='ignore'):
        usable = (reading >= lidar.range_min) & (reading <= lidar.range_max)
        sees = usable & (reading <= reach * (1.0 + margin[1]) + margin[0])
    misses: npt.NDArray[np.bool_] = ~sees
    return misses


_SLAB = compiled(_slab_loop)


def _nearest_loop(
    xs: Any,
    ys: Any,
    ox: float,
    oy: float,
    xx: float,
    xy: float,
    yx: float,
    yy: float,
    angle_min: float,
    increment: float,
    turn: int,
    reading: Any,
    wanted: Any,
    within: float,
    gap: Any,
    best: Any,
) -> None:
    """`nearest_pixels` one point at a time: for each slot set in `wanted`, the index in
    `best` (-1: none) of the point whose range from the sensor at (ox, oy) (rows of the
    rotation: xx xy / yx yy) lies nearest `reading` there, within `within` (`gap`: how near).

    Compiled: it runs on every output scan over the frame's slab pixels. For the 43 520 of
    the benchmark's frame (`benchmarks/bench_memory.py`) numpy's arctan2, hypot and a sort
    took 2.8 ms, this loop 0.74 ms (each measured while an evaluation ran beside it)."""
    count = reading.size
    scale = 1.0 / increment
    for i in range(xs.size):
        dx = xs[i] - ox
        dy = ys[i] - oy
        x = xx * dx + xy * dy
        y = yx * dx + yy * dy
        # As `_forget_and_project_loop`: the slot whose interval holds the bearing.
        centre = (fast_atan2(y, x) - angle_min) * scale + 0.5
        if not 0.0 <= centre < turn:
            centre -= turn * math.floor(centre / turn)
        slot = int(centre)
        if slot >= count or not wanted[slot]:
            continue  # outside a grid that is not a full turn, or not asked for
        off = abs(math.sqrt(x * x + y * y) - reading[slot])
        if off <= within and off < gap[slot]:  # False against NaN: no reading
            gap[slot] = off
            best[slot] = i


_NEAREST = compiled(_nearest_loop)


def nearest_pixels(
    x: F64, y: F64, scan: Scan, slots: npt.NDArray[np.bool_], sensor: Placement, within: float
) -> npt.NDArray[np.int64]:
    """Per slot of `scan` set in `slots`, the point (odometry frame) in it, seen from
    `sensor`, whose range lies nearest the slot's reading, if within `within` metres of it:
    their indices, one per slot that has one, in slot order."""
    grid = scan.grid
    best = np.full(len(scan), -1, dtype=np.int64)
    if x.size == 0 or not slots.any():
        return best[:0]
    _NEAREST(
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(y, dtype=np.float64),
        sensor.x, sensor.y, sensor.xx, sensor.xy, sensor.yx, sensor.yy,
        grid.angle_min, grid.angle_increment, round(TWO_PI / abs(grid.angle_increment)),
        _usable_reading(scan, np.arange(len(scan))), np.ascontiguousarray(slots),
        within, np.full(len(scan), np.inf), best,
    )  # fmt: skip
    chosen: npt.NDArray[np.int64] = best[best >= 0]
    return chosen


def _reach_and_slot(
    x: F64, y: F64, grid: AngleGrid, sensor: Placement
) -> tuple[F64, npt.NDArray[np.int64]]:
    """Per point (odometry frame): its range from `sensor` and its slot of `grid`."""
    dx, dy = x - sensor.x, y - sensor.y
    sx = sensor.xx * dx + sensor.xy * dy
    sy = sensor.yx * dx + sensor.yy * dy
    slot: npt.NDArray[np.int64] = grid.slot_of(np.arctan2(sy, sx))
    return np.hypot(sx, sy), slot


def _usable_reading(scan: Scan, slot: npt.NDArray[np.int64]) -> F64:
    """`scan`'s finite in-range reading in each slot; NaN for none or outside the grid."""
    ranges = scan.ranges.astype(np.float64)
    reading = np.where(
        (slot >= 0) & (slot < ranges.size), ranges[np.clip(slot, 0, ranges.size - 1)], np.nan
    )
    with np.errstate(invalid='ignore'):
        usable = (reading >= scan.range_min) & (reading <= scan.range_max)
    return np.where(usable, reading, np.nan)


def _not_nearer(reach: F64, reading: F64) -> npt.NDArray[np.bool_]:
    with np.errstate(invalid='ignore'):
        keep: npt.NDArray[np.bool_] = reach >= reading  # False against NaN: no reading
    return keep


def _unseen(reach: F64, reading: F64, margin: tuple[float, float]) -> npt.NDArray[np.bool_]:
    with np.errstate(invalid='ignore'):
        sees = reading <= reach * (1.0 + margin[1]) + margin[0]  # False against NaN
    return ~sees


def not_nearer_than(x: F64, y: F64, scan: Scan, sensor: Placement) -> npt.NDArray[np.bool_]:
    """Which points (odometry frame) lie in a slot of `scan` with a finite in-range reading,
    seen from `sensor`, no nearer than that reading.

    The obstacle scan's reading is its robust near edge (the near cluster of a slot's
    points): a pixel nearer than it is the short tail of depth noise, or too few to be an
    obstacle at all where the slot reads free.
    """
    reach, slot = _reach_and_slot(x, y, scan.grid, sensor)
    return _not_nearer(reach, _usable_reading(scan, slot))


def unseen_by(
    x: F64, y: F64, lidar: Scan, sensor: Placement, margin: tuple[float, float]
) -> npt.NDArray[np.bool_]:
    """Which points (odometry frame) the LiDAR at `sensor` does not see: its reading in the
    point's slot is not a finite in-range range, or lies beyond the point by more than
    `margin` (metres, share of the range).

    What the LiDAR sees at its own height it sees again from anywhere: the memory need not
    keep it, and a wall kept on drifting odometry stands in front of the wall.
    """
    reach, slot = _reach_and_slot(x, y, lidar.grid, sensor)
    return _unseen(reach, _usable_reading(lidar, slot), margin)


def worth_remembering(
    x: F64, y: F64, depth_scan: Scan, lidar: Scan, sensor: Placement, margin: tuple[float, float]
) -> npt.NDArray[np.bool_]:
    """`not_nearer_than(depth_scan) & unseen_by(lidar)`, each point's bearing found once
    when the two scans share a grid (they do in the stream: both on the output grid)."""
    if depth_scan.grid != lidar.grid:
        near = not_nearer_than(x, y, depth_scan, sensor)
        return near & unseen_by(x, y, lidar, sensor, margin)
    reach, slot = _reach_and_slot(x, y, lidar.grid, sensor)
    near = _not_nearer(reach, _usable_reading(depth_scan, slot))
    return near & _unseen(reach, _usable_reading(lidar, slot), margin)
