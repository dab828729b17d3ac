"""Indoor worlds of the paper as MJCF strings, with every obstacle's true geometry.

Each world is generated from parameters and a seed. Every obstacle is a vertical
prism: a footprint polygon (world frame, metres, counter-clockwise) extruded over
a height span [z_min, z_max] above the floor (z = 0), and carries a `kind` label
so that the evaluation can split its metrics by obstacle type. The MJCF geoms are
built from the same numbers, so the ground truth and the simulated sensors see
one geometry.

Drop-off worlds (`ledge`, `stairs`, `hole`) have no floor plane at z = 0: the floor is
solid blocks with their tops at z = 0 everywhere but over each `Drop` (an axis-aligned
rectangle where the floor is missing), and a plane named `floor` lies at the bottom of
the deepest drop. The robot really falls there. The truth scan holds each drop's
rectangle as an obstacle footprint (`TruthScanner`): its nearest edge is where the
robot must stop.

Terrain worlds (`ramp-12`, `ramp-8`, `ramp-ledge`, `sills`) have ground that is not one
plane: `Ground` pieces (ramps, platforms, door sills) whose surfaces are floor, not obstacles.
Each piece is an axis-aligned rectangle whose top rises linearly along x; `World.surface_height`
is the height of the ground the robot drives on at any place. An obstacle standing on raised
ground carries that ground's height (`Obstacle.ground`): every height of the collision slab is
measured above it, so a ramp's surface is never an obstacle and a box on it is.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.sim.errors import SimError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import numpy.typing as npt

    Polygon = npt.NDArray[np.float64]

KINDS = (
    'wall',
    'shelf_board',
    'shelf_side',
    'barricade_base',
    'barricade_top',
    'chair_leg',
    'chair_seat',
    'lamp_base',
    'lamp_pole',
    'low_box',
    'cable_tray',
)
DROP_KINDS = ('ledge', 'stairs', 'hole')
# A circle's footprint polygon may lie inside the true circle by at most this
# much (the sagitta of one edge), metres: far below the sensors' 1 mm resolution.
MAX_SAGITTA = 2e-4
WALL_THICKNESS = 0.1
WALL_HEIGHT = 1.2
BOARD_THICKNESS = 0.018


@dataclass(frozen=True)
class Obstacle:
    """One MuJoCo geom of the world with its true shape.

    `footprint` is the (N, 2) polygon of the geom seen from above (world frame,
    counter-clockwise); the geom fills it between heights `z_min` and `z_max`.
    """

    name: str
    kind: str
    footprint: Polygon
    z_min: float
    z_max: float
    mjcf: str = field(repr=False)
    # Height of the ground it stands on (the lowest under its footprint), metres: the slab's
    # heights are measured above it (0 on the floor; a ramp's or a platform's surface).
    ground: float = 0.0

    def __post_init__(self) -> None:
        footprint = np.asarray(self.footprint, dtype=np.float64)
        if footprint.ndim != 2 or footprint.shape[0] < 3 or footprint.shape[1] != 2:
            msg = f'obstacle {self.name!r} needs an (N >= 3, 2) footprint, got {footprint.shape}'
            raise SimError(msg)
        x, y = footprint[:, 0], footprint[:, 1]
        if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0.0:
            footprint = footprint[::-1]  # the truth scan relies on counter-clockwise order
        object.__setattr__(self, 'footprint', footprint)

    def overlaps_slab(self, low: float, high: float) -> bool:
        """Whether any part of the obstacle lies at a height above its ground inside [low, high]."""
        return self.z_min - self.ground <= high and self.z_max - self.ground >= low

    @property
    def top(self) -> float:
        """Height of its top above the ground it stands on, metres."""
        return self.z_max - self.ground


@dataclass(frozen=True)
class Drop:
    """A rectangle of the floor that is missing: x_min..x_max by y_min..y_max (world, metres).

    `depth` is how far below z = 0 the bottom lies. A staircase (`steps` > 1) descends
    along +x in `steps` equal rises, each tread `(x_max - x_min) / steps` long; its last
    tread is the bottom.
    """

    name: str
    kind: str
    rectangle: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max
    depth: float
    steps: int = 1

    def __post_init__(self) -> None:
        x_min, x_max, y_min, y_max = self.rectangle
        if not (x_max > x_min and y_max > y_min):
            msg = f'drop {self.name!r} needs x_min < x_max and y_min < y_max, got {self.rectangle}'
            raise SimError(msg)
        if not 0.0 < self.depth <= 5.0:
            msg = f'drop {self.name!r} depth {self.depth} m must be in (0, 5] m'
            raise SimError(msg)
        if self.steps < 1:
            msg = f'drop {self.name!r} needs at least one step, got {self.steps}'
            raise SimError(msg)

    @property
    def footprint(self) -> Polygon:
        """Counter-clockwise corners of the missing floor."""
        x_min, x_max, y_min, y_max = self.rectangle
        return np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]])

    def contains(self, x: float, y: float) -> bool:
        x_min, x_max, y_min, y_max = self.rectangle
        return x_min < x < x_max and y_min < y < y_max

    def treads(self) -> list[tuple[float, float, float]]:
        """(x_min, x_max, top z) of every tread above the bottom, top step first."""
        x_min, x_max, _, _ = self.rectangle
        run = (x_max - x_min) / self.steps
        rise = self.depth / self.steps
        return [
            (x_min + index * run, x_min + (index + 1) * run, -(index + 1) * rise)
            for index in range(self.steps - 1)
        ]


GROUND_KINDS = ('ramp', 'platform', 'sill')
# The group of the solids the robot drives on over a run of ground pieces (`ground_solids`):
# they collide and no sensor sees them (the pieces themselves are seen and do not collide).
GROUND_SOLID_GROUP = 4
# A ground piece's solid reaches this far below its lowest surface (into the floor beneath),
# metres: its mesh never has two vertices in one place, and no gap shows at its foot.
GROUND_FOOTING = 0.01


@dataclass(frozen=True)
class Ground:
    """A piece of ground above (or below) the floor: a ramp, a platform or a door sill.

    Over the rectangle x_min..x_max by y_min..y_max (world, metres) its top surface rises
    linearly along x from `z_start` (at x_min) to `z_end` (at x_max); it is solid down to
    below both. Its surface is floor: the robot drives on it and it is never an obstacle.
    """

    name: str
    kind: str
    rectangle: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max
    z_start: float
    z_end: float

    def __post_init__(self) -> None:
        x_min, x_max, y_min, y_max = self.rectangle
        if not (x_max > x_min and y_max > y_min):
            msg = (
                f'ground {self.name!r} needs x_min < x_max and y_min < y_max, got {self.rectangle}'
            )
            raise SimError(msg)
        if self.kind not in GROUND_KINDS:
            msg = f'ground {self.name!r} kind {self.kind!r} is not one of {", ".join(GROUND_KINDS)}'
            raise SimError(msg)

    @property
    def slope(self) -> float:
        """Rise per metre along +x (negative: going down)."""
        x_min, x_max, _, _ = self.rectangle
        return (self.z_end - self.z_start) / (x_max - x_min)

    @property
    def footprint(self) -> Polygon:
        x_min, x_max, y_min, y_max = self.rectangle
        return np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]])

    def contains(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.bool_]:
        x_min, x_max, y_min, y_max = self.rectangle
        inside: npt.NDArray[np.bool_] = (x >= x_min) & (x <= x_max) & (y >= y_min) & (y <= y_max)
        return inside

    def height(self, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Its surface's height at x (along the rise; outside its x span, the nearer end's)."""
        x_min, x_max, _, _ = self.rectangle
        along = np.clip(x, x_min, x_max) - x_min
        rise: npt.NDArray[np.float64] = self.z_start + self.slope * along
        return rise

    def mjcf(self, rgba: str) -> str:
        """A convex mesh geom (its asset inline through `asset`) named after the piece, seen
        by the sensors; the robot drives on its run's solid (`ground_solids`) instead."""
        return (
            f'<geom name="{self.name}" type="mesh" mesh="{self.name}_mesh" pos="0 0 0" '
            f'contype="0" conaffinity="0" {rgba}/>'
        )

    def asset(self) -> str:
        return _prism_mesh(f'{self.name}_mesh', [self])


def _prism_mesh(name: str, pieces: Sequence[Ground]) -> str:
    """A mesh asset under the top surfaces of `pieces` (one after another along x, one y span),
    down to `GROUND_FOOTING` below their lowest point."""
    _, _, y_min, y_max = pieces[0].rectangle
    bottom = min(min(piece.z_start, piece.z_end) for piece in pieces) - GROUND_FOOTING
    tops = [(pieces[0].rectangle[0], pieces[0].z_start)]
    tops += [(piece.rectangle[1], piece.z_end) for piece in pieces]
    vertices = [(x, y, z) for x, top in tops for y in (y_min, y_max) for z in (bottom, top)]
    return f'<mesh name="{name}" vertex="{_fmt(*np.ravel(vertices))}"/>'


def ground_runs(pieces: Sequence[Ground]) -> list[list[Ground]]:
    """The ground pieces in runs the robot drives on as one convex solid: one after another
    along x over one y span, each piece's surface starting where the last one's ends, none
    rising more steeply than the one before (a sill: bevel up, top, bevel down; a ramp: up,
    platform, down).

    Two solids meeting under a crest touch the robot at the edge between them: MuJoCo's
    contact with the higher one's end face there points along the floor and stops a wheel or
    a caster as a step would (the sprung robot reared up and tipped over at door sills). One
    solid has no such edge.
    """
    runs: list[list[Ground]] = []
    for piece in sorted(pieces, key=lambda p: (p.rectangle[2], p.rectangle[3], p.rectangle[0])):
        last = runs[-1][-1] if runs else None
        if (
            last is not None
            and last.rectangle[2:] == piece.rectangle[2:]
            and math.isclose(last.rectangle[1], piece.rectangle[0], abs_tol=1e-9)
            and math.isclose(last.z_end, piece.z_start, abs_tol=1e-9)
            and piece.slope <= last.slope
        ):
            runs[-1].append(piece)
        else:
            runs.append([piece])
    return runs


def ground_solids(pieces: Sequence[Ground]) -> list[tuple[str, str, str]]:
    """(geom name, geom MJCF, mesh asset) of the solid under each run of ground pieces
    (`ground_runs`): it collides with the robot, and no sensor sees it."""
    solids = []
    for run in ground_runs(pieces):
        name = f'{run[0].name}_solid'
        geom = (
            f'<geom name="{name}" type="mesh" mesh="{name}_mesh" pos="0 0 0" '
            f'group="{GROUND_SOLID_GROUP}" rgba="0 0 0 0" friction="1 0.005 0.0001"/>'
        )
        solids.append((name, geom, _prism_mesh(f'{name}_mesh', run)))
    return solids


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: position (metres) and heading (radians, counter-clockwise from +x)."""

    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class World:
    """A generated world: its obstacles, MJCF assets, robot start pose and extent."""

    name: str
    seed: int
    obstacles: tuple[Obstacle, ...]
    start: Pose2D
    bounds: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max of the room inside
    assets: tuple[str, ...] = ()
    drops: tuple[Drop, ...] = ()
    ground: tuple[Ground, ...] = ()

    def kind_of(self, geom_name: str) -> str:
        """The kind label of an obstacle geom ('floor' for the floor, '' for robot parts)."""
        return self.kinds().get(geom_name, '')

    def kinds(self) -> dict[str, str]:
        """Geom name -> kind, for every obstacle and every piece of floor ('floor')."""
        kinds = {name: 'floor' for name, _ in self._floor_pieces()}
        kinds.update({piece.name: 'floor' for piece in self.ground})
        kinds.update({name: 'floor' for name, _, _ in ground_solids(self.ground)})
        kinds.update({obstacle.name: obstacle.kind for obstacle in self.obstacles})
        return kinds

    @property
    def floor_depth(self) -> float:
        """Depth of the lowest floor below z = 0 (0 without drops)."""
        return max((drop.depth for drop in self.drops), default=0.0)

    def worldbody_mjcf(self) -> str:
        """The floor and every obstacle geom, to be placed in `<worldbody>`."""
        pieces = [geom for _, geom in self._floor_pieces()]
        pieces += [piece.mjcf(GROUND_RGBA) for piece in self.ground]
        pieces += [geom for _, geom, _ in ground_solids(self.ground)]
        return '\n'.join([*pieces, *(obstacle.mjcf for obstacle in self.obstacles)])

    def all_assets(self) -> tuple[str, ...]:
        """The obstacles' mesh assets and every ground piece's."""
        solids = (mesh for _, _, mesh in ground_solids(self.ground))
        return (*self.assets, *(piece.asset() for piece in self.ground), *solids)

    def surface_height(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """Height of the ground to drive on at each place, metres: the highest ground piece
        there, else the floor (z = 0; over a drop too: its floor is missing, not lower)."""
        return surface_height(self.ground, x, y)

    def on_slope(self, x: float, y: float, reach: float = 0.0) -> bool:
        """Whether a sloped piece of ground (a ramp) lies within `reach` of (x, y), metres."""
        for piece in self.ground:
            if piece.kind != 'ramp':
                continue
            x_min, x_max, y_min, y_max = piece.rectangle
            dx = max(x_min - x, 0.0, x - x_max)
            dy = max(y_min - y, 0.0, y - y_max)
            if math.hypot(dx, dy) <= reach:
                return True
        return False

    def _floor_pieces(self) -> list[tuple[str, str]]:
        """(geom name, MJCF) of the floor: one plane, or blocks around the drops and a plane
        at the bottom of the deepest."""
        extent = 2.0 + max(abs(value) for value in self.bounds)
        rgba = 'rgba="0.8 0.8 0.8 1" friction="1 0.005 0.0001"'
        bottom = -self.floor_depth
        plane_mjcf = (
            f'<geom name="floor" type="plane" pos="0 0 {bottom:.6g}" '
            f'size="{extent:.3f} {extent:.3f} 0.1" {rgba}/>'
        )
        plane = ('floor', plane_mjcf)
        if not self.drops:
            return [plane]
        pieces = [plane]
        blocks = _floor_blocks([d.rectangle for d in self.drops], extent)
        for index, (x0, x1, y0, y1) in enumerate(blocks):
            pieces.append(_block(f'floor_{index}', (x0, x1, y0, y1), (bottom, 0.0), rgba))
        for drop in self.drops:
            _, _, y0, y1 = drop.rectangle
            for index, (x0, x1, top) in enumerate(drop.treads()):
                name = f'{drop.name}_tread_{index}'
                pieces.append(_block(name, (x0, x1, y0, y1), (bottom, top), rgba))
        return pieces


GROUND_RGBA = 'rgba="0.75 0.75 0.7 1" friction="1 0.005 0.0001"'


def _block(
    name: str, area: tuple[float, float, float, float], z: tuple[float, float], rgba: str
) -> tuple[str, str]:
    x0, x1, y0, y1 = area
    centre = _fmt((x0 + x1) / 2, (y0 + y1) / 2, (z[0] + z[1]) / 2)
    half = _fmt((x1 - x0) / 2, (y1 - y0) / 2, (z[1] - z[0]) / 2)
    geom = f'<geom name="{name}" type="box" pos="{centre}" size="{half}" {rgba}/>'
    return name, geom


def _floor_blocks(
    holes: list[tuple[float, float, float, float]], extent: float
) -> list[tuple[float, float, float, float]]:
    """Rectangles covering [-extent, extent]^2 except the holes: the cells of the grid the
    holes' sides make, free ones merged along x within each band of y."""
    xs = sorted({-extent, extent, *(v for h in holes for v in h[:2])})
    ys = sorted({-extent, extent, *(v for h in holes for v in h[2:])})
    blocks = []
    for y0, y1 in itertools.pairwise(ys):
        run: list[float] = []
        for x0, x1 in itertools.pairwise(xs):
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            free = not any(h[0] < cx < h[1] and h[2] < cy < h[3] for h in holes)
            if free:
                run = [run[0] if run else x0, x1]
            elif run:
                blocks.append((run[0], run[1], y0, y1))
                run = []
        if run:
            blocks.append((run[0], run[1], y0, y1))
    return blocks


# ---------------------------------------------------------------- shapes


def _fmt(*values: float) -> str:
    return ' '.join(f'{value:.6g}' for value in values)


def rectangle(cx: float, cy: float, half_x: float, half_y: float, yaw: float = 0.0) -> Polygon:
    """Counter-clockwise corners of a rectangle centred at (cx, cy) turned by `yaw`."""
    corners = np.array([[-half_x, -half_y], [half_x, -half_y], [half_x, half_y], [-half_x, half_y]])
    c, s = math.cos(yaw), math.sin(yaw)
    turned: Polygon = corners @ np.array([[c, s], [-s, c]]) + np.array([cx, cy])
    return turned


def circle(cx: float, cy: float, radius: float) -> Polygon:
    """A polygon inscribed in the circle, fine enough that no point lies MAX_SAGITTA inside."""
    half_angle = math.acos(max(-1.0, 1.0 - MAX_SAGITTA / radius))
    count = max(8, math.ceil(math.pi / half_angle))
    angles = np.linspace(0.0, 2.0 * math.pi, count, endpoint=False)
    return np.column_stack([cx + radius * np.cos(angles), cy + radius * np.sin(angles)])


def regular_polygon(cx: float, cy: float, radius: float, sides: int, phase: float) -> Polygon:
    """Vertices of a regular polygon of circumradius `radius`, first vertex at angle `phase`."""
    angles = phase + np.arange(sides) * (2.0 * math.pi / sides)
    return np.column_stack([cx + radius * np.cos(angles), cy + radius * np.sin(angles)])


def box(
    name: str,
    kind: str,
    centre: tuple[float, float],
    half: tuple[float, float],
    z: tuple[float, float],
    *,
    yaw: float = 0.0,
    rgba: str = '0.6 0.5 0.4 1',
) -> Obstacle:
    z_min, z_max = z
    geom = (
        f'<geom name="{name}" type="box" pos="{_fmt(centre[0], centre[1], (z_min + z_max) / 2)}" '
        f'size="{_fmt(half[0], half[1], (z_max - z_min) / 2)}" euler="0 0 {yaw:.6g}" '
        f'rgba="{rgba}"/>'
    )
    footprint = rectangle(centre[0], centre[1], half[0], half[1], yaw)
    return Obstacle(name, kind, footprint, z_min, z_max, geom)


def cylinder(
    name: str,
    kind: str,
    centre: tuple[float, float],
    radius: float,
    z: tuple[float, float],
    *,
    rgba: str = '0.4 0.4 0.5 1',
) -> Obstacle:
    z_min, z_max = z
    geom = (
        f'<geom name="{name}" type="cylinder" '
        f'pos="{_fmt(centre[0], centre[1], (z_min + z_max) / 2)}" '
        f'size="{_fmt(radius, (z_max - z_min) / 2)}" rgba="{rgba}"/>'
    )
    return Obstacle(name, kind, circle(centre[0], centre[1], radius), z_min, z_max, geom)


def prism(
    name: str, kind: str, footprint: Polygon, z: tuple[float, float], rgba: str = '0.7 0.3 0.2 1'
) -> tuple[Obstacle, str]:
    """A convex polygonal prism as a MuJoCo mesh; returns the obstacle and its mesh asset."""
    z_min, z_max = z
    centre = footprint.mean(axis=0)
    local = footprint - centre
    vertices = [(*point, height) for height in (z_min, z_max) for point in local]
    asset = f'<mesh name="{name}_mesh" vertex="{_fmt(*np.ravel(vertices))}"/>'
    geom = (
        f'<geom name="{name}" type="mesh" mesh="{name}_mesh" '
        f'pos="{_fmt(centre[0], centre[1], 0.0)}" rgba="{rgba}"/>'
    )
    return Obstacle(name, kind, np.array(footprint, dtype=np.float64), z_min, z_max, geom), asset


def room_walls(
    bounds: tuple[float, float, float, float],
    door: tuple[float, float] | None = None,
    *,
    bottom: float = 0.0,
) -> list[Obstacle]:
    """Four walls whose inner faces are `bounds`; `door` = (x centre, width) cuts the +y wall.

    `bottom` (z, metres) is where they start: below zero down to a drop's bottom.
    """
    x_min, x_max, y_min, y_max = bounds
    t = WALL_THICKNESS / 2
    z = (bottom, WALL_HEIGHT)
    rgba = '0.9 0.9 0.85 1'
    walls = [
        box(
            'wall_south',
            'wall',
            ((x_min + x_max) / 2, y_min - t),
            ((x_max - x_min) / 2 + 2 * t, t),
            z,
            rgba=rgba,
        ),
        box(
            'wall_west',
            'wall',
            (x_min - t, (y_min + y_max) / 2),
            (t, (y_max - y_min) / 2),
            z,
            rgba=rgba,
        ),
        box(
            'wall_east',
            'wall',
            (x_max + t, (y_min + y_max) / 2),
            (t, (y_max - y_min) / 2),
            z,
            rgba=rgba,
        ),
    ]
    left, right = x_min - 2 * t, x_max + 2 * t
    pieces = [(left, right)]
    if door is not None:
        centre, width = door
        pieces = [(left, centre - width / 2), (centre + width / 2, right)]
    for index, (start, end) in enumerate(pieces):
        if end - start > 1e-6:
            walls.append(
                box(
                    f'wall_north_{index}',
                    'wall',
                    ((start + end) / 2, y_max + t),
                    ((end - start) / 2, t),
                    z,
                    rgba=rgba,
                )
            )
    return walls


# ---------------------------------------------------------------- furniture

# Board bottoms, metres above the floor: a LiDAR plane at 0.30 m passes between
# the boards at 0.232-0.250 and 0.400-0.418, as in the paper's bookshelf world.
SHELF_BOARD_BOTTOMS = (0.06, 0.232, 0.40, 0.62, 0.982)


def bookshelf(
    prefix: str,
    front_x: float,
    centre_y: float,
    *,
    width: float = 0.8,
    depth: float = 0.3,
    height: float = 1.0,
    board_bottoms: tuple[float, ...] = SHELF_BOARD_BOTTOMS,
) -> list[Obstacle]:
    """A bookshelf facing -x, front at `front_x`: two side panels and thin boards, no back."""
    t = BOARD_THICKNESS
    cx = front_x + depth / 2
    side_y = width / 2 - t / 2
    parts = [
        box(
            f'{prefix}_side_{side}',
            'shelf_side',
            (cx, centre_y + sign * side_y),
            (depth / 2, t / 2),
            (0.0, height),
        )
        for side, sign in (('left', 1.0), ('right', -1.0))
    ]
    inner = width / 2 - t
    for index, bottom in enumerate(board_bottoms):
        if bottom + t > height + 1e-9:
            msg = f'shelf board at {bottom} m does not fit in a {height} m bookshelf'
            raise SimError(msg)
        parts.append(
            box(
                f'{prefix}_board_{index}',
                'shelf_board',
                (cx, centre_y),
                (depth / 2, inner),
                (bottom, bottom + t),
            )
        )
    return parts


def barricade(
    prefix: str,
    centre: tuple[float, float],
    *,
    base_radius: float = 0.35,
    base_height: float = 0.2,
    top_radius: float = 0.12,
    top_height: float = 0.8,
    sides: int = 6,
) -> tuple[list[Obstacle], list[str]]:
    """A polygonal base (circumradius `base_radius`, a vertex pointing to -x) under a cylinder."""
    footprint = regular_polygon(centre[0], centre[1], base_radius, sides, math.pi)
    base, asset = prism(f'{prefix}_base', 'barricade_base', footprint, (0.0, base_height))
    top = cylinder(f'{prefix}_top', 'barricade_top', centre, top_radius, (base_height, top_height))
    return [base, top], [asset]


def chair(prefix: str, centre: tuple[float, float], yaw: float) -> list[Obstacle]:
    """A chair: seat board at 0.43-0.46 m on four thin legs (radius 12 mm)."""
    half = 0.21
    leg_radius = 0.012
    c, s = math.cos(yaw), math.sin(yaw)
    parts = [
        box(
            f'{prefix}_seat',
            'chair_seat',
            centre,
            (half, half),
            (0.43, 0.46),
            yaw=yaw,
            rgba='0.5 0.3 0.2 1',
        )
    ]
    inset = half - leg_radius - 0.01
    for index, (dx, dy) in enumerate(((1, 1), (1, -1), (-1, -1), (-1, 1))):
        x = centre[0] + inset * (dx * c - dy * s)
        y = centre[1] + inset * (dx * s + dy * c)
        parts.append(
            cylinder(f'{prefix}_leg_{index}', 'chair_leg', (x, y), leg_radius, (0.0, 0.43))
        )
    return parts


def floor_lamp(prefix: str, centre: tuple[float, float]) -> list[Obstacle]:
    """A floor lamp: a low wide base (radius 0.16 m, 4 cm high) and a thin pole to 1.6 m."""
    return [
        cylinder(f'{prefix}_base', 'lamp_base', centre, 0.16, (0.0, 0.04), rgba='0.2 0.2 0.2 1'),
        cylinder(f'{prefix}_pole', 'lamp_pole', centre, 0.015, (0.04, 1.6), rgba='0.7 0.7 0.7 1'),
    ]


def low_box(
    prefix: str, centre: tuple[float, float], yaw: float, size: tuple[float, float, float]
) -> Obstacle:
    length, width, height = size
    return box(
        prefix,
        'low_box',
        centre,
        (length / 2, width / 2),
        (0.0, height),
        yaw=yaw,
        rgba='0.8 0.6 0.2 1',
    )


def cable_tray(
    prefix: str, centre: tuple[float, float], yaw: float, length: float = 1.2
) -> Obstacle:
    """A cable protector lying on the floor: 12 cm wide, 4 cm high."""
    half = (length / 2, 0.06)
    return box(prefix, 'cable_tray', centre, half, (0.0, 0.04), yaw=yaw, rgba='0.1 0.1 0.1 1')


# ---------------------------------------------------------------- worlds

SMALL_ROOM = (-1.5, 2.8, -2.0, 2.0)
LARGE_ROOM = (-3.0, 3.0, -2.5, 2.5)
ROBOT_AT_ORIGIN = Pose2D(0.0, 0.0, 0.0)
# Free space kept around the robot's start pose when placing clutter, metres.
START_CLEARANCE = 0.8


def room_world(seed: int = 0) -> World:
    """An empty room with a door gap in its +y wall; the robot starts in a corner, facing +x."""
    walls = room_walls(LARGE_ROOM, door=(1.5, 0.9))
    return World('room', seed, tuple(walls), Pose2D(-2.0, -1.5, 0.0), LARGE_ROOM)


def bookshelf_world(seed: int = 0, *, distance: float = 2.0) -> World:
    """A bookshelf straight ahead, its front `distance` m away, a wall 0.5 m behind it."""
    bounds = (SMALL_ROOM[0], distance + 0.8, SMALL_ROOM[2], SMALL_ROOM[3])
    obstacles = room_walls(bounds) + bookshelf('shelf', distance, 0.0)
    return World('bookshelf', seed, tuple(obstacles), ROBOT_AT_ORIGIN, bounds)


def barricade_world(seed: int = 0, *, distance: float = 2.0) -> World:
    """A barricade whose centre is `distance` m straight ahead of the robot."""
    parts, assets = barricade('barricade', (distance, 0.0))
    obstacles = room_walls(SMALL_ROOM) + parts
    return World('barricade', seed, tuple(obstacles), ROBOT_AT_ORIGIN, SMALL_ROOM, tuple(assets))


def clutter_world(seed: int = 0) -> World:
    """A room with a bookshelf, a barricade and, placed at random by `seed`, chairs, a lamp,
    low boxes (5-15 cm) and a cable tray."""
    rng = np.random.default_rng(seed)
    x_min, x_max, y_min, y_max = LARGE_ROOM
    start = Pose2D(-2.2, 0.0, 0.0)
    obstacles = room_walls(LARGE_ROOM) + bookshelf('shelf', x_max - 0.3, 1.2)
    parts, assets = barricade('barricade', (x_max - 1.0, -1.3))
    obstacles += parts
    taken: list[tuple[float, float, float]] = [
        (start.x, start.y, START_CLEARANCE),
        (x_max - 0.15, 1.2, 0.5),
        (x_max - 1.0, -1.3, 0.45),
    ]

    def place(radius: float) -> tuple[float, float, float]:
        for _ in range(1000):
            x = float(rng.uniform(x_min + radius + 0.05, x_max - radius - 0.05))
            y = float(rng.uniform(y_min + radius + 0.05, y_max - radius - 0.05))
            if all(math.hypot(x - ox, y - oy) > radius + r for ox, oy, r in taken):
                taken.append((x, y, radius))
                return x, y, float(rng.uniform(-math.pi, math.pi))
        msg = (
            f'clutter world (seed {seed}) has no free place left for an object of radius {radius} m'
        )
        raise SimError(msg)

    for index in range(2):
        x, y, yaw = place(0.32)
        obstacles += chair(f'chair{index}', (x, y), yaw)
    x, y, _ = place(0.2)
    obstacles += floor_lamp('lamp', (x, y))
    for index in range(3):
        size = (
            float(rng.uniform(0.15, 0.4)),
            float(rng.uniform(0.15, 0.3)),
            float(rng.uniform(0.05, 0.15)),
        )
        x, y, yaw = place(0.5 * math.hypot(size[0], size[1]) + 0.05)
        obstacles.append(low_box(f'box{index}', (x, y), yaw, size))
    x, y, yaw = place(0.65)
    obstacles.append(cable_tray('cable_tray', (x, y), yaw))
    return World('clutter', seed, tuple(obstacles), start, LARGE_ROOM, tuple(assets))


# ---------------------------------------------------------------- drop-offs

DROP_ROOM = (-1.5, 4.5, -2.0, 2.0)
# Where the ledge world's robot starts: 0.5 m from the south wall, facing +x, so that the
# straight line to a goal on the walkway past the ledge crosses into the yard 0.45 m deep.
DROP_START = Pose2D(0.0, -1.5, 0.0)


def _drop_world(name: str, seed: int, drops: tuple[Drop, ...], start: Pose2D) -> World:
    bottom = -max(drop.depth for drop in drops)
    walls = room_walls(DROP_ROOM, bottom=bottom)
    return World(name, seed, tuple(walls), start, DROP_ROOM, drops=drops)


def ledge_world(
    seed: int = 0, *, edge: float = 2.0, walkway: float = 0.3, depth: float = 0.4
) -> World:
    """A loading dock: the floor ends at x = `edge` (a `depth` m drop to the yard) for every
    y below `walkway`; north of it a walkway runs on to the east wall."""
    x_max, y_min = DROP_ROOM[1], DROP_ROOM[2]
    dock = Drop('ledge', 'ledge', (edge, x_max, y_min, walkway), depth)
    return _drop_world('ledge', seed, (dock,), DROP_START)


def stairs_world(
    seed: int = 0,
    *,
    edge: float = 1.6,
    width: float = 1.2,
    steps: int = 4,
    rise: float = 0.17,
    run: float = 0.3,
) -> World:
    """A stairwell straight ahead: `steps` rises of `rise` m going down along +x from
    x = `edge`, each tread `run` m long, the last one the bottom landing; floor all round."""
    half = width / 2
    well = Drop('stairs', 'stairs', (edge, edge + steps * run, -half, half), steps * rise, steps)
    return _drop_world('stairs', seed, (well,), ROBOT_AT_ORIGIN)


def hole_world(
    seed: int = 0,
    *,
    near: float = 1.5,
    length: float = 0.8,
    width: float = 1.0,
    depth: float = 0.5,
) -> World:
    """An open floor hatch straight ahead: `length` by `width` m, its near side at x = `near`."""
    half = width / 2
    hatch = Drop('hole', 'hole', (near, near + length, -half, half), depth)
    return _drop_world('hole', seed, (hatch,), ROBOT_AT_ORIGIN)


# ---------------------------------------------------------------- terrain

RAMP_WIDTH = 1.2  # metres between the ramp's side walls (or its wall and its ledge)
RAMP_RISE = 0.15  # metres from the floor to the platform
RAMP_FOOT = 1.6  # x of the up ramp's foot: the robot starts at the origin facing it
PLATFORM_LENGTH = 1.2  # metres of level platform between the up and the down ramp
TERRAIN_HALF_WIDTH = 1.3  # the terrain rooms' inner half width, metres
RUN_OUT = 1.8  # metres of floor past the down ramp's foot
TERRAIN_JITTER = 0.04  # metres, a seeded box's shift
TERRAIN_BOX_HEIGHTS = (0.06, 0.12)  # metres above the ground it stands on


def surface_height(
    pieces: tuple[Ground, ...] | list[Ground],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """The highest of `pieces` at each place, the floor (0) where none is."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    height = np.zeros(np.broadcast(x, y).shape)
    covered = np.zeros(height.shape, dtype=bool)
    for piece in pieces:
        inside = piece.contains(x, y)
        top = np.broadcast_to(piece.height(x), height.shape)
        height = np.where(inside & covered, np.maximum(height, top), height)
        height = np.where(inside & ~covered, top, height)
        covered |= inside
    return height


def ramp_pieces(
    prefix: str, foot: float, grade: float, rise: float, half_width: float
) -> list[Ground]:
    """A ramp of 1:`grade` up from the floor at x = `foot` to a level platform `rise` m high,
    `PLATFORM_LENGTH` long, and an equal ramp down again; `half_width` either side of y = 0."""
    run = grade * rise
    top = foot + run
    down = top + PLATFORM_LENGTH
    sides = (-half_width, half_width)
    return [
        Ground(f'{prefix}_up', 'ramp', (foot, top, *sides), 0.0, rise),
        Ground(f'{prefix}_platform', 'platform', (top, down, *sides), rise, rise),
        Ground(f'{prefix}_down', 'ramp', (down, down + run, *sides), rise, 0.0),
    ]


def box_on_ground(
    name: str,
    pieces: tuple[Ground, ...] | list[Ground],
    centre: tuple[float, float],
    half: tuple[float, float],
    height: float,
    *,
    yaw: float = 0.0,
) -> Obstacle:
    """A low box standing on whatever ground is under it: its top `height` m above the ground
    at its centre, its bottom at the lowest ground under its corners (the rest of it is sunk
    into the slope), that lowest ground its `ground`."""
    corners = rectangle(centre[0], centre[1], half[0], half[1], yaw)
    under = surface_height(pieces, corners[:, 0], corners[:, 1])
    at_centre = float(surface_height(pieces, np.array([centre[0]]), np.array([centre[1]]))[0])
    ground = float(under.min())
    obstacle = box(
        name, 'low_box', centre, half, (ground, at_centre + height), yaw=yaw, rgba='0.8 0.6 0.2 1'
    )
    return replace(obstacle, ground=ground)


def _terrain_box(
    rng: np.random.Generator,
    name: str,
    pieces: list[Ground],
    centre: tuple[float, float],
    half: tuple[float, float],
) -> Obstacle:
    dx, dy = rng.uniform(-TERRAIN_JITTER, TERRAIN_JITTER, 2)
    height = float(rng.uniform(*TERRAIN_BOX_HEIGHTS))
    return box_on_ground(name, pieces, (centre[0] + dx, centre[1] + dy), half, height)


def _side_wall(name: str, x: tuple[float, float], y: tuple[float, float]) -> Obstacle:
    """A solid wall block filling x by y (a ramp's side)."""
    return box(
        name,
        'wall',
        ((x[0] + x[1]) / 2, (y[0] + y[1]) / 2),
        ((x[1] - x[0]) / 2, (y[1] - y[0]) / 2),
        (0.0, WALL_HEIGHT),
        rgba='0.9 0.9 0.85 1',
    )


def ramp_world(
    seed: int = 0, *, grade: float = 12.0, rise: float = RAMP_RISE, blocked: bool = False
) -> World:
    """A ramp of 1:`grade` up to a platform and down again, between walls (a corridor between
    two wings), `RAMP_WIDTH` wide, its foot 1.6 m ahead of the robot.

    Low boxes (6-12 cm above the ground under them, seeded heights and shifts): one on the up
    ramp and one on the platform, each against a side wall (the passage beside it is 0.85 m
    or more); one on the floor beside the ramp's mouth, one in the approach, one past the
    down ramp's foot. `blocked`: the platform's box stands on the ramp's centre line instead.
    """
    rng = np.random.default_rng(seed + 11000)
    half = RAMP_WIDTH / 2
    pieces = ramp_pieces('ramp', RAMP_FOOT, grade, rise, half)
    foot, end = pieces[0].rectangle[0], pieces[-1].rectangle[1]
    bounds = (-1.0, end + RUN_OUT, -TERRAIN_HALF_WIDTH, TERRAIN_HALF_WIDTH)
    obstacles = room_walls(bounds)
    for sign, wall in ((1.0, 'left'), (-1.0, 'right')):
        low, high = sorted((sign * half, sign * TERRAIN_HALF_WIDTH))
        obstacles.append(_side_wall(f'ramp_wall_{wall}', (foot, end), (low, high)))
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    up, platform = pieces[0].rectangle, pieces[1].rectangle
    size = (0.15, 0.1)
    obstacles += [
        _terrain_box(rng, 'box_on_ramp', pieces, ((up[0] + up[1]) / 2, side * 0.46), size),
        _terrain_box(
            rng,
            'box_on_platform',
            pieces,
            ((platform[0] + platform[1]) / 2, 0.0 if blocked else -side * 0.46),
            size,
        ),
        _terrain_box(rng, 'box_beside_ramp', pieces, (foot - 0.35, side * 0.95), size),
        _terrain_box(rng, 'box_approach', pieces, (0.75, -side * 0.55), size),
        _terrain_box(rng, 'box_run_out', pieces, (end + 0.6, side * 0.6), size),
    ]
    name = f'ramp-{grade:g}'
    return World(name, seed, tuple(obstacles), ROBOT_AT_ORIGIN, bounds, ground=tuple(pieces))


def ramp12_world(seed: int = 0) -> World:
    """A wheelchair ramp, 1:12 (4.8 degrees), 0.15 m up to a platform and down again."""
    return ramp_world(seed, grade=12.0)


def ramp8_world(seed: int = 0) -> World:
    """A steeper ramp, 1:8 (7.1 degrees), 0.15 m up to a platform and down again."""
    return ramp_world(seed, grade=8.0)


LEDGE_DEPTH = 0.4  # metres from the floor down to the yard beside the ledge ramp
LEDGE_START = Pose2D(0.0, -0.85, 0.0)


def ramp_ledge_world(
    seed: int = 0, *, grade: float = 8.0, rise: float = RAMP_RISE, depth: float = LEDGE_DEPTH
) -> World:
    """A 1:`grade` ramp up to a platform and down again with a ledge along its right side:
    the floor south of the ramp is missing (a yard `depth` m down) for the ramp's whole
    length; a wall runs along its left side.

    The robot starts south of the ramp's centre line: the straight line to its goal, past the
    ramp, crosses the yard; the ramp is the way. A low box stands on the platform against the
    wall (seeded).
    """
    rng = np.random.default_rng(seed + 12000)
    half = RAMP_WIDTH / 2
    pieces = ramp_pieces('ramp', RAMP_FOOT, grade, rise, half)
    foot, end = pieces[0].rectangle[0], pieces[-1].rectangle[1]
    bounds = (-1.0, end + RUN_OUT, -TERRAIN_HALF_WIDTH, TERRAIN_HALF_WIDTH)
    yard = Drop('ledge', 'ledge', (foot, end, -TERRAIN_HALF_WIDTH, -half), depth)
    obstacles = room_walls(bounds, bottom=-depth)
    obstacles.append(_side_wall('ramp_wall_left', (foot, end), (half, TERRAIN_HALF_WIDTH)))
    middle = (pieces[1].rectangle[0] + pieces[1].rectangle[1]) / 2
    obstacles.append(_terrain_box(rng, 'box_on_platform', pieces, (middle, 0.46), (0.15, 0.1)))
    return World(
        'ramp-ledge',
        seed,
        tuple(obstacles),
        LEDGE_START,
        bounds,
        drops=(yard,),
        ground=tuple(pieces),
    )


SILL_BEVEL = 2.0  # a sill's bevel runs this many times its height (1:2, 27 degrees)
SILL_TOP = 0.04  # metres of level top, across the door's wall
DOOR_WIDTH = 0.9


def sill_pieces(prefix: str, x: float, height: float, y: tuple[float, float]) -> list[Ground]:
    """A door sill across x = `x`: a bevel up, a level top `SILL_TOP` long, a bevel down."""
    bevel = SILL_BEVEL * height
    left, right = x - SILL_TOP / 2, x + SILL_TOP / 2
    return [
        Ground(f'{prefix}_in', 'sill', (left - bevel, left, *y), 0.0, height),
        Ground(f'{prefix}_top', 'sill', (left, right, *y), height, height),
        Ground(f'{prefix}_out', 'sill', (right, right + bevel, *y), height, 0.0),
    ]


def sills_world(seed: int = 0) -> World:
    """Three rooms in a row joined by doors 0.9 m wide, each door with a sill 1-2 cm high
    (bevelled 1:2, seeded heights and door positions); a low box in the middle room beside the
    line between the doors."""
    rng = np.random.default_rng(seed + 13000)
    bounds = (-1.0, 5.6, -1.5, 1.5)
    obstacles = room_walls(bounds)
    pieces: list[Ground] = []
    t = WALL_THICKNESS / 2
    for index, x in enumerate((1.5, 3.6)):
        centre = float(rng.uniform(-0.25, 0.25))
        height = float(rng.uniform(0.01, 0.02))
        low, high = centre - DOOR_WIDTH / 2, centre + DOOR_WIDTH / 2
        obstacles.append(_side_wall(f'door{index}_right', (x - t, x + t), (bounds[2], low)))
        obstacles.append(_side_wall(f'door{index}_left', (x - t, x + t), (high, bounds[3])))
        pieces += sill_pieces(f'sill{index}', x, height, (low, high))
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    obstacles.append(_terrain_box(rng, 'box_middle', pieces, (2.55, side * 0.55), (0.15, 0.1)))
    return World('sills', seed, tuple(obstacles), ROBOT_AT_ORIGIN, bounds, ground=tuple(pieces))


WORLDS: dict[str, Callable[[int], World]] = {
    'room': room_world,
    'bookshelf': bookshelf_world,
    'barricade': barricade_world,
    'clutter': clutter_world,
    'ledge': ledge_world,
    'stairs': stairs_world,
    'hole': hole_world,
    'ramp-12': ramp12_world,
    'ramp-8': ramp8_world,
    'ramp-ledge': ramp_ledge_world,
    'sills': sills_world,
}
TERRAIN_WORLDS = ('ramp-12', 'ramp-8', 'ramp-ledge', 'sills')


def make_world(name: str, seed: int = 0) -> World:
    """The world called `name` (one of `WORLDS`) generated with `seed`."""
    builder = WORLDS.get(name)
    if builder is None:
        msg = f'unknown world {name!r}; choose one of {", ".join(WORLDS)}'
        raise SimError(msg)
    return builder(seed)
