"""Simulated 2D LiDAR and depth camera: named profiles, ray casting, noise models.

Both sensors cast all their rays in one `mujoco.mj_multiRay` call per frame. The
robot's own geoms (group 3) and the solids under the ground pieces (group 4, which only
collide) are excluded through the `geomgroup` argument.

Noise (switchable, seeded):

- LiDAR: Gaussian range noise, sigma 1 cm, and rare dropouts reported as +Inf
  (no return), as a real driver does. Returns beyond range_max are +Inf, those
  nearer than range_min -Inf (REP-117).
- Depth: Gaussian noise along the optical axis with sigma = k Z^2, k = 0.01 /m
  (1 % of Z at 1 m, 2 % at 2 m, the growth of a stereo camera's error with
  distance); pixels on the far side of a depth edge (a 4-neighbour nearer by
  more than 5 % of its depth) are invalid (0), as are pixels outside
  [range_min, range_max]. Images are 16UC1 millimetres (REP-118), 0 = no measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from scanfuse.camera import CameraModel
from scanfuse.scan import AngleGrid
from scanfuse.sim.errors import SimError
from scanfuse.sim.robot import ROBOT_GEOM_GROUP
from scanfuse.sim.worlds import GROUND_SOLID_GROUP

if TYPE_CHECKING:
    import numpy.typing as npt

    Matrix = npt.NDArray[np.float64]

OPTICAL_FRAME = 'camera_depth_optical_frame'
# Geom groups a ray may hit: every group except the robot's and the ground's solids.
HIDDEN_GROUPS = (ROBOT_GEOM_GROUP, GROUND_SOLID_GROUP)
VISIBLE_GROUPS = np.array([int(g not in HIDDEN_GROUPS) for g in range(6)], dtype=np.uint8)


@dataclass(frozen=True)
class LidarProfile:
    """A planar LiDAR: its angular grid, rate and range limits."""

    name: str
    angle_min: float
    angle_increment: float
    count: int
    rate: float
    range_min: float
    range_max: float

    @property
    def grid(self) -> AngleGrid:
        return AngleGrid(self.angle_min, self.angle_increment, self.count)

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.count - 1)


LIDARS: dict[str, LidarProfile] = {
    # 360 degrees in 1080 slots: the last reading is one increment short of +pi.
    'rplidar-a2': LidarProfile(
        'rplidar-a2', -math.pi, 2.0 * math.pi / 1080, 1080, 10.0, 0.15, 12.0
    ),
    # 270 degrees with both ends measured: 1081 readings.
    'hokuyo-ust10lx': LidarProfile(
        'hokuyo-ust10lx',
        -math.radians(135.0),
        math.radians(270.0) / 1080,
        1081,
        40.0,
        0.02,
        10.0,
    ),
}


@dataclass(frozen=True)
class CloudProfile:
    """A 3D LiDAR publishing PointCloud2: azimuth steps over 360 degrees, elevation rings.

    Each cloud is cast at once at its stamp and delivered `latency` later (the driver's
    integration and transfer); readings outside [range_min, range_max] are left out.
    """

    name: str
    azimuths: int
    elevation_min: float
    elevation_max: float
    rings: int
    rate: float
    range_min: float
    range_max: float
    latency: float = 0.02
    sigma: float = 0.02  # metres along the ray, with noise on


CLOUDS: dict[str, CloudProfile] = {
    # A Livox Mid-360's field of view (360 x -7..52 degrees), its non-repetitive pattern
    # sampled on a fixed grid of 1-degree azimuths and 20 rings, 10 Hz.
    'mid360': CloudProfile(
        'mid360', 360, math.radians(-7.0), math.radians(52.0), 20, 10.0, 0.1, 40.0
    ),
}


def cloud_profile(name: str) -> CloudProfile:
    profile = CLOUDS.get(name)
    if profile is None:
        msg = f'unknown point-cloud LiDAR profile {name!r}; choose one of {", ".join(CLOUDS)}'
        raise SimError(msg)
    return profile


def cloud_directions(profile: CloudProfile) -> Matrix:
    """Unit rays of every azimuth on every ring (sensor frame: x forward, z up)."""
    azimuth = 2.0 * math.pi * np.arange(profile.azimuths) / profile.azimuths - math.pi
    elevation = np.linspace(profile.elevation_min, profile.elevation_max, profile.rings)
    az, el = np.meshgrid(azimuth, elevation)
    rays = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    return rays.reshape(-1, 3)


def cloud_points(
    distances: npt.NDArray[np.float64],
    directions: Matrix,
    profile: CloudProfile,
    noise: bool,
    rng: np.random.Generator,
) -> npt.NDArray[np.float32]:
    """x, y, z (N x 3, sensor frame) of the returns within range, noisy along the ray."""
    ranges = distances.copy()
    if noise:
        ranges += rng.normal(0.0, profile.sigma, ranges.shape)
    with np.errstate(invalid='ignore'):
        kept = np.isfinite(ranges) & (ranges >= profile.range_min) & (ranges <= profile.range_max)
    points: npt.NDArray[np.float32] = (directions[kept] * ranges[kept, None]).astype(np.float32)
    return points


@dataclass(frozen=True)
class CameraProfile:
    """A depth camera: field of view, resolutions, rate, range limits.

    Pixels are square and the focal length follows from the vertical field of
    view, so the 16:9 modes span the nominal horizontal field of view and 640x480
    is a 4:3 crop of it (about 73 degrees), as on the real D435 depth stream.
    """

    name: str
    horizontal_fov: float
    vertical_fov: float
    resolutions: tuple[tuple[int, int], ...]
    rate: float
    range_min: float
    range_max: float

    def model(self, width: int, height: int) -> CameraModel:
        """The pinhole model of this camera at `width` x `height` (principal point centred)."""
        if (width, height) not in self.resolutions:
            modes = ', '.join(f'{w}x{h}' for w, h in self.resolutions)
            msg = f'{self.name} has no {width}x{height} mode; use one of {modes}'
            raise SimError(msg)
        focal = (height / 2) / math.tan(self.vertical_fov / 2)
        return CameraModel.from_intrinsics(
            width, height, focal, focal, (width - 1) / 2, (height - 1) / 2, frame_id=OPTICAL_FRAME
        )


CAMERAS: dict[str, CameraProfile] = {
    'd435': CameraProfile(
        'd435',
        math.radians(87.0),
        math.radians(58.0),
        ((640, 480), (848, 480), (1280, 720), (640, 360), (480, 270), (424, 240), (256, 144)),
        30.0,
        0.2,
        10.0,
    ),
}


def lidar_profile(name: str) -> LidarProfile:
    profile = LIDARS.get(name)
    if profile is None:
        msg = f'unknown LiDAR profile {name!r}; choose one of {", ".join(LIDARS)}'
        raise SimError(msg)
    return profile


def camera_profile(name: str) -> CameraProfile:
    profile = CAMERAS.get(name)
    if profile is None:
        msg = f'unknown camera profile {name!r}; choose one of {", ".join(CAMERAS)}'
        raise SimError(msg)
    return profile


@dataclass(frozen=True)
class LidarNoise:
    sigma: float = 0.01  # metres
    dropout: float = 0.001  # probability of no return per reading


@dataclass(frozen=True)
class DepthNoise:
    k: float = 0.01  # sigma = k Z^2, 1/metres
    edge_jump: float = 0.05  # neighbour jump, as a fraction of depth, that invalidates a pixel


class DepthBackend(str, Enum):
    """How depth images are made."""

    AUTO = 'auto'  # the renderer where MUJOCO_GL names a working headless GL, else rays
    MULTIRAY = 'multiray'  # one mj_multiRay ray per pixel (no OpenGL needed)
    RENDERER = 'renderer'  # mujoco.Renderer depth buffer (needs MUJOCO_GL=egl or osmesa)


# ---------------------------------------------------------------- ray casting


class RayFan:
    """Rays from one origin, cast together with one `mj_multiRay` call."""

    def __init__(self, directions: Matrix, cutoff: float) -> None:
        self.directions = np.ascontiguousarray(directions, dtype=np.float64)
        # Rotating (3, N) columns and copying back is several times faster than (N, 3) @ R.T.
        self._columns = np.ascontiguousarray(self.directions.T)
        self.count = self.directions.shape[0]
        self.cutoff = cutoff
        self._geomid = np.zeros(self.count, dtype=np.int32)
        self._dist = np.zeros(self.count, dtype=np.float64)

    def cast(
        self, model: mujoco.MjModel, data: mujoco.MjData, origin: Matrix, rotation: Matrix
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int32]]:
        """Distances along each ray (NaN: nothing hit) and the geom hit (-1: none).

        `rotation` turns the sensor-frame directions into the world frame. The
        returned arrays are reused by the next call.
        """
        world = np.ascontiguousarray((rotation @ self._columns).T).reshape(-1)
        mujoco.mj_multiRay(
            model,
            data,
            np.asarray(origin, dtype=np.float64),
            world,
            VISIBLE_GROUPS,
            1,
            -1,
            self._geomid,
            self._dist,
            None,
            self.count,
            self.cutoff,
        )
        dist = self._dist
        dist[self._geomid < 0] = np.nan
        return dist, self._geomid


def lidar_directions(profile: LidarProfile) -> Matrix:
    angles = profile.grid.angles()
    return np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])


def lidar_ranges(
    distances: npt.NDArray[np.float64],
    profile: LidarProfile,
    noise: LidarNoise | None,
    rng: np.random.Generator,
) -> npt.NDArray[np.float32]:
    """LaserScan ranges from true distances: noise, dropouts, REP-117 limits."""
    ranges = distances.copy()
    if noise is not None:
        ranges += rng.normal(0.0, noise.sigma, ranges.shape)
    with np.errstate(invalid='ignore'):
        ranges[np.isnan(ranges) | (ranges > profile.range_max)] = np.inf
        ranges[ranges < profile.range_min] = -np.inf
    if noise is not None and noise.dropout > 0.0:
        ranges[rng.random(ranges.shape) < noise.dropout] = np.inf
    out: npt.NDArray[np.float32] = ranges.astype(np.float32)
    return out


def optical_rays(camera: CameraModel) -> tuple[Matrix, npt.NDArray[np.float64]]:
    """Unit rays through every pixel centre (optical frame, row-major) and their z components.

    Depth along the optical axis is the hit distance times the z component.
    """
    u = (np.arange(camera.width, dtype=np.float64) - camera.cx) / camera.fx
    v = (np.arange(camera.height, dtype=np.float64) - camera.cy) / camera.fy
    x_n, y_n = np.meshgrid(u, v)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1).reshape(-1, 3)
    norm = np.linalg.norm(rays, axis=1)
    return rays / norm[:, None], (1.0 / norm).reshape(camera.height, camera.width)


def depth_edges(depth: npt.NDArray[np.float64], jump: float) -> npt.NDArray[np.bool_]:
    """Pixels behind a depth edge: a 4-neighbour is nearer by more than `jump` times its depth.

    Only the far side of a jump is flagged, where a stereo camera's matching mixes
    foreground and background; the near side keeps its depth, so thin foreground
    objects (a shelf board a pixel or two high) stay visible. A pixel next to one
    with no return (NaN) is flagged too.
    """
    edges = np.zeros(depth.shape, dtype=bool)
    with np.errstate(invalid='ignore'):
        for first, second, first_edges, second_edges in (
            (depth[:-1, :], depth[1:, :], edges[:-1, :], edges[1:, :]),
            (depth[:, :-1], depth[:, 1:], edges[:, :-1], edges[:, 1:]),
        ):
            nearer = np.fmin(first, second)
            big = (np.abs(first - second) > jump * nearer) | (np.isnan(first) != np.isnan(second))
            # views into `edges`: flag whichever of the pair is farther (or has no return)
            np.logical_or(first_edges, big & ~(first <= second), out=first_edges)
            np.logical_or(second_edges, big & ~(second <= first), out=second_edges)
    return edges


def depth_image(
    depth: npt.NDArray[np.float64],
    profile: CameraProfile,
    noise: DepthNoise | None,
    rng: np.random.Generator,
) -> npt.NDArray[np.uint16]:
    """16UC1 millimetres from true depth along the optical axis (NaN: nothing hit).

    Invalid (0): outside [range_min, range_max] and, with noise on, at depth edges.
    """
    z = depth
    invalid = np.isnan(z)
    if noise is not None:
        invalid |= depth_edges(z, noise.edge_jump)
        z = z + rng.standard_normal(z.shape) * (noise.k * z * z)
    with np.errstate(invalid='ignore'):
        invalid |= (z < profile.range_min) | (z > profile.range_max)
    millimetres = np.rint(np.where(invalid, 0.0, z) * 1000.0)
    return millimetres.astype(np.uint16)
