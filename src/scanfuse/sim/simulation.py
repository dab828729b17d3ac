"""The simulation: a world, the robot, its sensors, ground truth, and the driving loop.

`Simulation.run` keeps real sensor time. Every sensor runs at its own rate and phase
from the start of the run, and every event happens at the physics step (2 ms by
default) nearest its nominal time, so a 30 Hz camera's stamps jitter by up to half a
step as a real one's do:

- **Depth camera** (`depth_rate`, default the profile's 30 Hz): the image is rendered at
  its exposure, stamped with the exposure time, and delivered (handed to the sink and
  the controller) `depth_latency` seconds later (default 40 ms).
- **LiDAR** (the profile's rate, 10 Hz for the RPLIDAR): a sweep starts at its stamp;
  beam i is measured at stamp + i * time_increment with time_increment = scan_time *
  angle_increment / (2 pi) (scan_time / readings for a 360 degree LiDAR, as rplidar_ros
  sets it; urg_node's value for a 270 degree one). Beams are cast in `lidar_chunks`
  chunks per sweep, each at the physics step nearest its middle beam's time, so no beam
  is more than half a chunk (plus half a step) off its own time. The scan is delivered
  at the end of the sweep, stamp + scan_time.
- **Odometry and state** (`state_rate`, 50 Hz): wheel odometry, the true pose and the
  robot's contacts.
- **A robot with several sensors** (`RobotSpec.lidars()`, `cameras()`, the `amr`): every
  LiDAR sweeps and every camera exposes on its own clock, the second one `sensor_stagger`
  of its period after the first (two free-running sensors are never in phase). Frames
  carry their sensor's source name; the controller steps on the first LiDAR's scans. A 3D
  LiDAR (`RobotSpec.cloud`, profile `SimConfig.cloud`) casts a whole cloud at once at its
  stamp, a quarter period after the start, and delivers it the profile's latency later.

- **IMU** (`imu_rate`, 100 Hz; 0: none): base_link's orientation in the world (its yaw
  included; noise `ImuNoise`), MuJoCo's gyro and accelerometer at base_link's origin, on
  every robot (`ImuSample`, recorded on /imu).

Falls: at every state sample the base's height is compared with where it settled, above the
ground under it (`World.surface_height`: a ramp's surface, a platform's); once it is more
than `FALL_DEPTH` lower, the base has left the ground (a ledge, a stair, a hole) and
`Simulation.fell_ns` holds the stamp of that first sample.

A scan's ground truth (`LidarFrame.truth`) is the exact truth scan from the LiDAR's true
pose at the scan's stamp (its first beam), the instant a de-skewed, motion-compensated
scan describes; a raw sweep of a turning robot differs from it by its skew.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Protocol

import mujoco
import numpy as np

from scanfuse.config import FusionConfig
from scanfuse.progress import NullProgress, Progress
from scanfuse.scan import Scan
from scanfuse.sim.errors import SimError
from scanfuse.sim.headless_gl import HEADLESS_BACKENDS
from scanfuse.sim.robot import (
    FALL_DEPTH,
    ROBOT_BODY,
    ROBOT_GEOM_GROUP,
    CameraMount,
    CloudMount,
    LidarMount,
    RobotSpec,
    WheelOdometry,
)
from scanfuse.sim.sensors import (
    HIDDEN_GROUPS,
    DepthBackend,
    DepthNoise,
    LidarNoise,
    RayFan,
    camera_profile,
    cloud_directions,
    cloud_points,
    cloud_profile,
    depth_image,
    lidar_directions,
    lidar_profile,
    lidar_ranges,
    optical_rays,
)
from scanfuse.sim.truth import TruthScanner
from scanfuse.sim.worlds import Pose2D, World, make_world

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel

    Matrix = npt.NDArray[np.float64]

NANOSECONDS = 1_000_000_000
# Stamps count from this instant (2023-11-14T22:13:20Z) rather than zero, which
# ROS tools treat as "latest"; the run is still fully deterministic.
EPOCH_NS = 1_700_000_000 * NANOSECONDS
SETTLE_TIME = 0.3
RIGID_TIMESTEP = 0.002  # seconds: a rigid robot's physics step
_DEFAULTS = FusionConfig()
# camera_link (x forward, z up) -> optical frame (z forward, x right, y down), REP-103.
LINK_TO_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
CAMERA_NAME = 'depth_camera'


def camera_name(mount: CameraMount) -> str:
    """The MJCF camera of a mount: `depth_camera` for the first, `depth_camera_<source>`."""
    return f'{CAMERA_NAME}_{mount.source}' if mount.source else CAMERA_NAME


def pitch_matrix(pitch: float) -> Matrix:
    """Rotation about +y by `pitch`: positive turns x towards -z (looks down)."""
    c, s = math.cos(pitch), math.sin(pitch)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def yaw_matrix(yaw: float) -> Matrix:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ImuNoise:
    """Gaussian noise of the simulated IMU: orientation (radians about each axis), angular
    velocity (rad/s), linear acceleration (m/s^2), one sigma each: a consumer-grade IMU's
    fused orientation holds pitch and roll to about 0.1 degree."""

    orientation: float = math.radians(0.1)
    angular_velocity: float = 0.002
    linear_acceleration: float = 0.02


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines one simulated run apart from the driving."""

    world: str = 'bookshelf'
    seed: int = 0
    lidar: str = 'rplidar-a2'
    camera: str = 'd435'
    resolution: tuple[int, int] = (640, 480)
    depth_rate: float | None = None  # Hz; None: the camera profile's rate
    depth_latency: float = 0.040  # seconds from exposure to delivery
    depth_phase: float = 0.0  # seconds from the run's start to the first exposure
    lidar_phase: float = 0.0  # seconds from the run's start to the first sweep
    lidar_chunks: int = 12  # ray casts per LiDAR sweep
    noise: bool = True
    lidar_noise: LidarNoise = field(default_factory=LidarNoise)
    depth_noise: DepthNoise = field(default_factory=DepthNoise)
    robot: RobotSpec = field(default_factory=RobotSpec)
    depth_backend: DepthBackend = DepthBackend.AUTO
    # Physics step, seconds; None: the robot's (`physics_step`).
    timestep: float | None = None
    state_rate: float = 50.0  # odometry, true pose and contact checks, Hz
    min_obstacle_height: float = _DEFAULTS.min_obstacle_height
    max_obstacle_height: float = _DEFAULTS.max_obstacle_height
    sensor_stagger: float = 0.5  # share of a period between a robot's two LiDARs (cameras)
    cloud: str = 'mid360'  # the 3D LiDAR's profile, on a robot that carries one
    imu_rate: float = 100.0  # Hz; 0: no IMU samples
    imu_noise: ImuNoise = field(default_factory=ImuNoise)

    def __post_init__(self) -> None:
        if self.depth_rate is not None and not 0.0 < self.depth_rate <= 1000.0:
            msg = f'depth_rate {self.depth_rate} Hz must be in (0, 1000]; 0 would record no images'
            raise SimError(msg)
        if self.timestep is not None and not 0.0 < self.timestep <= 0.01:
            msg = f'timestep {self.timestep} s must be in (0, 0.01] for stable wheel contacts'
            raise SimError(msg)
        for name in ('depth_latency', 'depth_phase', 'lidar_phase'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                msg = f'{name} {value} s must be in [0, 1] s'
                raise SimError(msg)
        if not 1 <= self.lidar_chunks <= 10000:
            msg = f'lidar_chunks {self.lidar_chunks} must be in [1, 10000] ray casts per sweep'
            raise SimError(msg)
        if not 0.0 < self.state_rate <= 1000.0:
            msg = f'state_rate {self.state_rate} Hz must be in (0, 1000]'
            raise SimError(msg)
        if not 0.0 <= self.imu_rate <= 1000.0:
            msg = f'imu_rate {self.imu_rate} Hz must be in [0, 1000] (0: no IMU)'
            raise SimError(msg)
        if not 0.0 <= self.sensor_stagger < 1.0:
            msg = f'sensor_stagger {self.sensor_stagger} must be in [0, 1) of a period'
            raise SimError(msg)

    @property
    def physics_step(self) -> float:
        """The physics step, seconds: `timestep`, else the robot's: a sprung robot's
        (`Suspension.timestep`) or `RIGID_TIMESTEP`."""
        if self.timestep is not None:
            return self.timestep
        spring = self.robot.suspension
        return RIGID_TIMESTEP if spring is None else spring.timestep


def fusion_config(config: SimConfig, base: FusionConfig | None = None) -> FusionConfig:
    """`base` (default: FusionConfig()) with the simulated robot's mounting and camera limits.

    What the evaluation hands to a FusionPipeline for a controller's scans, so that the
    fusion uses the same extrinsics as the recorded /tf_static.
    """
    robot = config.robot
    camera = camera_profile(config.camera)
    if robot.several:
        return _named_fusion_config(config, base or FusionConfig())
    return (base or FusionConfig()).with_changes(
        camera_x=robot.camera_x,
        camera_y=0.0,
        camera_height=robot.camera_height,
        camera_roll=0.0,
        camera_pitch=robot.camera_pitch,
        camera_yaw=0.0,
        lidar_x=robot.lidar_x,
        lidar_y=robot.lidar_y,
        lidar_height=robot.lidar_height,
        lidar_yaw=robot.lidar_yaw,
        range_min=camera.range_min,
        range_max=camera.range_max,
        min_obstacle_height=config.min_obstacle_height,
        max_obstacle_height=config.max_obstacle_height,
    )


def _placement(mount: LidarMount | CloudMount | CameraMount) -> dict[str, float]:
    """A sensor's pose in base_link as a named source's parameters give it."""
    return {'x': mount.x, 'y': mount.y, 'z': mount.z, 'yaw': mount.yaw}


def _named_fusion_config(config: SimConfig, base: FusionConfig) -> FusionConfig:
    """A robot with several sensors: each one a named source (examples/scanfuse_multi.yaml),
    the output a 360-degree scan in the first LiDAR's frame (`full_circle`)."""
    robot = config.robot
    camera = camera_profile(config.camera)
    # The first named LiDAR and camera set the one-source mounting parameters.
    values = base.model_dump(exclude={'sources'})
    lidars = robot.lidars()
    cameras = robot.cameras()
    values['lidars'] = [mount.source for mount in lidars]
    for mount in lidars:
        values[mount.source] = {'topic': mount.topic, **_placement(mount)}
    if robot.cloud is not None:
        cloud = robot.cloud
        values['clouds'] = [cloud.source]
        values[cloud.source] = {
            'topic': cloud.topic,
            **_placement(cloud),
            'range_max': OBSTACLE_CLOUD_RANGE,
        }
    values['cameras'] = [mount.source for mount in cameras]
    for cam in cameras:
        values[cam.source] = {
            'depth_topic': cam.depth_topic,
            'camera_info_topic': cam.info_topic,
            **_placement(cam),
            'pitch': cam.pitch,
        }
    values.update(
        full_circle=True,
        range_min=camera.range_min,
        range_max=camera.range_max,
        min_obstacle_height=config.min_obstacle_height,
        max_obstacle_height=config.max_obstacle_height,
    )
    return FusionConfig.from_dict(values)


# RobotSpec's sensor poses, named as FusionConfig names them (fusion_config's inverse).
MOUNTING_PARAMETERS = (
    'lidar_x',
    'lidar_y',
    'lidar_height',
    'lidar_yaw',
    'camera_x',
    'camera_height',
    'camera_pitch',
)
# Mounting parameters the default simulated robot cannot follow: its camera sits on its
# centre line looking straight ahead (pitch only), its LiDAR level.
UNSIMULATED_MOUNTING = (
    'lidar_roll',
    'lidar_pitch',
    'camera_y',
    'camera_roll',
    'camera_yaw',
)


def robot_mounting(config: FusionConfig) -> dict[str, float]:
    """The simulated robot's sensor poses (RobotSpec fields) as `config` mounts them.

    Raises SimError for a mounting the simulated robot cannot have (off its centre line,
    a tilted LiDAR), rather than simulating a different robot than the file describes.
    """
    off = {name: getattr(config, name) for name in UNSIMULATED_MOUNTING}
    off = {name: value for name, value in off.items() if value != 0.0}
    if off:
        given = ', '.join(f'{name}={value:g}' for name, value in off.items())
        msg = (
            f'the default simulated robot carries its camera on its centre line, turned by '
            f'pitch only, and its LiDAR level; it cannot be mounted with {given}: set '
            f'{"/".join(off)} to 0 in the parameter file for the simulation'
        )
        raise SimError(msg)
    return {name: float(getattr(config, name)) for name in MOUNTING_PARAMETERS}


@dataclass(frozen=True)
class LidarFrame:
    """One LiDAR scan, the ground-truth obstacle scan of the same slots, and the true pose.

    Truth, pose and origin are at the scan's stamp (its first beam); `delivered_ns` is
    when the driver handed the scan over (the end of the sweep).
    """

    stamp_ns: int
    scan: Scan
    truth: Scan
    pose: Pose2D  # base_link in the world
    origin: tuple[float, float, float]  # LiDAR origin in the world
    delivered_ns: int | None = None  # None: the stamp (a scan cast all at once)
    source: str = ''  # the LiDAR's source name ('' : the default robot's one LiDAR)
    heading: float | None = None  # LiDAR heading in the world (None: the pose's yaw)

    @property
    def arrival_ns(self) -> int:
        return self.stamp_ns if self.delivered_ns is None else self.delivered_ns

    @property
    def lidar_yaw(self) -> float:
        """The LiDAR's heading in the world: where its scan's angle 0 points."""
        return self.pose.yaw if self.heading is None else self.heading


@dataclass(frozen=True)
class DepthFrame:
    """A depth image stamped with its exposure time, delivered `delivered_ns`."""

    stamp_ns: int
    depth: npt.NDArray[np.uint16]
    camera: CameraModel
    delivered_ns: int | None = None  # None: the stamp (no latency)
    source: str = ''  # the camera's source name ('' : the default robot's one camera)

    @property
    def arrival_ns(self) -> int:
        return self.stamp_ns if self.delivered_ns is None else self.delivered_ns


@dataclass(frozen=True)
class CloudFrame:
    """A 3D LiDAR's points (N x 3, its frame), stamped when cast, delivered `delivered_ns`."""

    stamp_ns: int
    points: npt.NDArray[np.float32]
    frame_id: str
    source: str
    delivered_ns: int

    @property
    def arrival_ns(self) -> int:
        return self.delivered_ns


@dataclass(frozen=True)
class StateSample:
    """Wheel odometry (odom frame) and the true pose (world frame) at one instant."""

    stamp_ns: int
    odometry: Pose2D
    v: float
    omega: float
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # quaternion x, y, z, w

    @property
    def true_pose(self) -> Pose2D:
        x, y, z, w = self.orientation
        return Pose2D(
            self.position[0],
            self.position[1],
            math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
        )


@dataclass(frozen=True)
class ImuSample:
    """What the IMU (frame base_link) measured at one instant: orientation in the world
    (quaternion x, y, z, w), angular velocity (rad/s) and linear acceleration (m/s^2, gravity
    included, as a sensor_msgs/Imu holds it), both in base_link."""

    stamp_ns: int
    orientation: tuple[float, float, float, float]
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]

    @property
    def roll_pitch(self) -> tuple[float, float]:
        """Roll and pitch (radians; pitch positive nose-down, REP-103) of the orientation."""
        x, y, z, w = self.orientation
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        return roll, pitch


@dataclass(frozen=True)
class Contact:
    """A contact between a robot geom and an obstacle geom."""

    stamp_ns: int
    position: tuple[float, float, float]
    robot_geom: str
    obstacle_geom: str
    kind: str


@dataclass(frozen=True)
class Observation:
    """What a controller sees when a LiDAR scan is delivered: the scan, the latest delivered
    depth image (None before the first), and the odometry now."""

    time: float
    scan: Scan
    depth: npt.NDArray[np.uint16] | None
    camera: CameraModel
    odometry: Pose2D


Controller = Callable[[Observation], tuple[float, float]]


class Sink(Protocol):
    """Receives everything the simulation produces, in time order."""

    def on_lidar(self, frame: LidarFrame) -> None: ...
    def on_depth(self, frame: DepthFrame) -> None: ...
    def on_state(self, sample: StateSample) -> None: ...
    def on_contacts(self, stamp_ns: int, contacts: list[Contact]) -> None: ...
    def on_cloud(self, frame: CloudFrame) -> None: ...
    def on_imu(self, sample: ImuSample) -> None: ...


@dataclass
class Trace:
    """A sink that keeps everything in memory (tests, evaluation)."""

    lidar: list[LidarFrame] = field(default_factory=list)
    depth: list[DepthFrame] = field(default_factory=list)
    states: list[StateSample] = field(default_factory=list)
    contacts: list[Contact] = field(default_factory=list)
    clouds: list[CloudFrame] = field(default_factory=list)
    imu: list[ImuSample] = field(default_factory=list)

    def on_lidar(self, frame: LidarFrame) -> None:
        self.lidar.append(frame)

    def on_imu(self, sample: ImuSample) -> None:
        self.imu.append(sample)

    def on_cloud(self, frame: CloudFrame) -> None:
        self.clouds.append(frame)

    def on_depth(self, frame: DepthFrame) -> None:
        self.depth.append(frame)

    def on_state(self, sample: StateSample) -> None:
        self.states.append(sample)

    def on_contacts(self, stamp_ns: int, contacts: list[Contact]) -> None:
        del stamp_ns  # every contact carries its own stamp
        self.contacts.extend(contacts)


# Events at the same physics step happen in this order.
_STATE, _EXPOSE, _SWEEP, _BEAMS, _DELIVER_DEPTH, _DELIVER_SCAN, _IMU = range(7)
# The examples' cloud range (examples/scanfuse_multi.yaml), metres from the output origin.
OBSTACLE_CLOUD_RANGE = 8.0


@dataclass
class _Sweep:
    """A LiDAR sweep in progress: the pose at its stamp and the beams cast so far."""

    lidar: int  # index into the robot's LiDARs
    stamp_ns: int
    pose: Pose2D
    origin: tuple[float, float, float]
    heading: float
    distances: npt.NDArray[np.float64]


def build_mjcf(world: World, robot: RobotSpec, config: SimConfig) -> str:
    """The whole scene: options, assets, the world's geoms, the robot and its actuators."""
    width, height = config.resolution
    camera = camera_profile(config.camera)
    camera_xml = ''
    for mount in robot.cameras():
        link = yaw_matrix(mount.yaw) @ pitch_matrix(mount.pitch)
        # MuJoCo cameras look along -z with +y up: x = -y_link, y = z_link.
        x_axis, y_axis = -link[:, 1], link[:, 2]
        camera_xml += (
            f'<camera name="{camera_name(mount)}" '
            f'pos="{mount.x:.6g} {mount.y:.6g} {mount.z:.6g}" '
            f'xyaxes="{" ".join(f"{v:.9g}" for v in (*x_axis, *y_axis))}" '
            f'fovy="{math.degrees(camera.vertical_fov):.9g}"/>'
        )
    # The camera belongs to the body that carries the sensors, not to a wheel.
    body = robot.mjcf(world.start, camera_xml)
    step = config.physics_step
    # Friction as stiff as the contact (elliptic cones, impratio 10): MuJoCo's default soft
    # friction lets a wheel creep under any traction, so the robot's wheels slipped 20 % of
    # the way up a 1:8 ramp where rubber (friction 1, 0.125 needed) holds.
    return f"""<mujoco model="scanfuse_{world.name}">
<compiler angle="radian"/>
<option timestep="{step:.6g}" integrator="implicitfast" cone="elliptic" impratio="10"/>
<visual><global offwidth="{width}" offheight="{height}"/><map znear="0.01" zfar="50"/></visual>
<asset>{''.join(world.all_assets())}</asset>
<worldbody>
<light pos="0 0 4" dir="0 0 -1" directional="true"/>
{world.worldbody_mjcf()}
{body}
</worldbody>
<contact>{robot.contact_mjcf()}</contact>
<actuator>{robot.actuators_mjcf()}</actuator>
<sensor>{robot.sensors_mjcf()}</sensor>
</mujoco>"""


class RendererDepth:
    """Depth from `mujoco.Renderer` (OpenGL): needs MUJOCO_GL=egl or osmesa set before import."""

    def __init__(self, model: mujoco.MjModel, camera: CameraModel, name: str = CAMERA_NAME) -> None:
        self._name = name
        try:
            self._renderer = mujoco.Renderer(model, camera.height, camera.width)
        except (mujoco.FatalError, AttributeError, RuntimeError, ImportError) as err:
            msg = (
                f'depth backend "renderer" needs OpenGL ({err}); set MUJOCO_GL=egl or '
                'MUJOCO_GL=osmesa before starting, or use the "multiray" backend'
            )
            raise SimError(msg) from err
        self._renderer.enable_depth_rendering()
        self._option = mujoco.MjvOption()
        for group in HIDDEN_GROUPS:
            self._option.geomgroup[group] = 0
        self._far = 0.999 * model.vis.map.zfar * model.stat.extent

    def depth(self, data: mujoco.MjData) -> npt.NDArray[np.float64]:
        self._renderer.update_scene(data, camera=self._name, scene_option=self._option)
        depth: npt.NDArray[np.float64] = self._renderer.render().astype(np.float64)
        depth[depth >= self._far] = np.nan
        return depth

    def close(self) -> None:
        self._renderer.close()


class Simulation:
    """A world with the robot in it; steps physics and produces sensor frames and truth.

    `run` drives it for a duration with a controller and hands every frame to a sink.
    """

    def __init__(self, config: SimConfig | None = None, world: World | None = None) -> None:
        self.config = config = config or SimConfig()
        self.world = world or make_world(config.world, config.seed)
        self.robot = config.robot
        self.lidar_profile = lidar_profile(config.lidar)
        self.camera_profile = camera_profile(config.camera)
        self.lidar_mounts: tuple[LidarMount, ...] = self.robot.lidars()
        self.camera_mounts: tuple[CameraMount, ...] = self.robot.cameras()
        model = self.camera_profile.model(*config.resolution)
        # One pinhole model per camera, in that camera's optical frame.
        self.cameras = [replace(model, frame_id=mount.frame) for mount in self.camera_mounts]
        self.camera = self.cameras[0]
        self.mjcf = build_mjcf(self.world, self.robot, config)
        try:
            self.model = mujoco.MjModel.from_xml_string(self.mjcf)
        except ValueError as err:
            msg = f'MuJoCo rejected the generated {self.world.name!r} world: {err}'
            raise SimError(msg) from err
        self.data = mujoco.MjData(self.model)
        self._body = self.model.body(ROBOT_BODY).id
        self._wheels = [self.model.joint(f'{side}_wheel').qposadr[0] for side in ('left', 'right')]
        self._geom_names = [self.model.geom(i).name for i in range(self.model.ngeom)]
        self._robot_geoms = self.model.geom_group == ROBOT_GEOM_GROUP
        self._kinds = self.world.kinds()
        self._floor = np.zeros(self.model.ngeom, dtype=bool)
        for name, kind in self._kinds.items():
            if kind == 'floor':
                self._floor[self.model.geom(name).id] = True
        directions = lidar_directions(self.lidar_profile)
        cutoff = self.lidar_profile.range_max + 1.0
        self._lidar_fan = RayFan(directions, cutoff=cutoff)
        beams = np.array_split(np.arange(self.lidar_profile.count), config.lidar_chunks)
        self._lidar_chunks = [
            (RayFan(directions[chunk], cutoff=cutoff), chunk) for chunk in beams if chunk.size
        ]
        self._step = 0  # physics steps since time zero
        self._step_ns = round(config.physics_step * NANOSECONDS)
        rays, self._z_of_ray = optical_rays(self.camera)
        self._depth_fan = RayFan(
            rays, cutoff=self.camera_profile.range_max / float(self._z_of_ray.min()) + 0.1
        )
        self.cloud_mount: CloudMount | None = self.robot.cloud
        self.cloud_profile = cloud_profile(config.cloud)
        self._cloud_directions = cloud_directions(self.cloud_profile)
        self._cloud_fan = (
            RayFan(self._cloud_directions, cutoff=self.cloud_profile.range_max + 1.0)
            if self.cloud_mount is not None
            else None
        )
        self._renderers = [
            self._make_renderer(config.depth_backend, camera, camera_name(mount))
            for camera, mount in zip(self.cameras, self.camera_mounts, strict=True)
        ]
        self.truth = TruthScanner(
            self.world.obstacles,
            self.lidar_profile.grid,
            min_obstacle_height=config.min_obstacle_height,
            max_obstacle_height=config.max_obstacle_height,
            range_max=self.lidar_profile.range_max,
            drops=self.world.drops,
        )
        self.fell_ns: int | None = None  # stamp of the state sample that found the base fallen
        self._rest_z = 0.0
        lidar_seed, depth_seed, *extra = np.random.SeedSequence(config.seed).spawn(
            len(self.lidar_mounts) + len(self.camera_mounts)
        )
        # The first LiDAR and camera draw as the one-sensor robot's; the others their own.
        self._lidar_rngs = [
            np.random.default_rng(seed)
            for seed in (lidar_seed, *extra[: len(self.lidar_mounts) - 1])
        ]
        self._depth_rngs = [
            np.random.default_rng(seed)
            for seed in (depth_seed, *extra[len(self.lidar_mounts) - 1 :])
        ]
        # Spawned after the others: adding the cloud changes no other sensor's noise.
        self._cloud_rng = np.random.default_rng(
            np.random.SeedSequence(config.seed).spawn(
                len(self.lidar_mounts) + len(self.camera_mounts) + 1
            )[-1]
        )
        self._imu_rng = np.random.default_rng(
            np.random.SeedSequence(config.seed).spawn(
                len(self.lidar_mounts) + len(self.camera_mounts) + 2
            )[-1]
        )
        self._gyro = self.model.sensor('imu_gyro').adr[0]
        self._accelerometer = self.model.sensor('imu_accelerometer').adr[0]
        self.odometry = WheelOdometry(self.robot.wheel_radius, self.robot.wheel_separation)
        self._settle()

    def _make_renderer(
        self, backend: DepthBackend, camera: CameraModel, name: str
    ) -> RendererDepth | None:
        if backend is DepthBackend.RENDERER:
            return RendererDepth(self.model, camera, name)
        if backend is DepthBackend.AUTO and os.environ.get('MUJOCO_GL') in HEADLESS_BACKENDS:
            try:
                return RendererDepth(self.model, camera, name)
            except SimError:
                return None  # the same depth by ray casting, only slower
        return None

    # ------------------------------------------------------------ state

    @property
    def time(self) -> float:
        return self._step * self.config.physics_step

    @property
    def stamp_ns(self) -> int:
        return EPOCH_NS + self._step * self._step_ns

    @property
    def lidar_time_increment(self) -> float:
        """Seconds between two beams: the sweep turns 2 pi in scan_time (rplidar_ros, urg_node)."""
        profile = self.lidar_profile
        return abs(profile.angle_increment) / (2.0 * math.pi) / profile.rate

    @property
    def depth_rate(self) -> float:
        return self.config.depth_rate or self.camera_profile.rate

    def geom_kind(self, geom_id: int) -> str:
        """The kind label of a geom ('floor', '' for the robot's own geoms)."""
        return self._kinds.get(self._geom_names[geom_id], '')

    def base_pose(self) -> tuple[Matrix, Matrix]:
        """Position and rotation matrix of base_link in the world."""
        return self.data.xpos[self._body].copy(), self.data.xmat[self._body].reshape(3, 3).copy()

    def true_pose(self) -> Pose2D:
        position, rotation = self.base_pose()
        return Pose2D(
            float(position[0]), float(position[1]), math.atan2(rotation[1, 0], rotation[0, 0])
        )

    def lidar_pose(self, lidar: int = 0) -> tuple[Matrix, Matrix]:
        """Origin and rotation (laser -> world) of the robot's LiDAR number `lidar`."""
        mount = self.lidar_mounts[lidar]
        position, rotation = self.base_pose()
        offset = np.array([mount.x, mount.y, mount.z])
        return position + rotation @ offset, rotation @ yaw_matrix(mount.yaw)

    def camera_pose(self, camera: int = 0) -> tuple[Matrix, Matrix]:
        """Optical-frame origin and rotation (optical -> world) of camera number `camera`."""
        mount = self.camera_mounts[camera]
        position, rotation = self.base_pose()
        offset = np.array([mount.x, mount.y, mount.z])
        link = rotation @ yaw_matrix(mount.yaw) @ pitch_matrix(mount.pitch)
        return position + rotation @ offset, link @ LINK_TO_OPTICAL

    def set_command(self, v: float, omega: float) -> None:
        """Body speed (m/s) and turn rate (rad/s), turned into wheel speed set points."""
        left, right = self.robot.wheel_speeds(v, omega)
        self.data.ctrl[:] = (left, right)

    def place(self, pose: Pose2D) -> None:
        """Put the robot at `pose` (at rest); its odometry restarts there at (0, 0, 0)."""
        self.data.qpos[0:3] = (pose.x, pose.y, self.data.qpos[2])
        self.data.qpos[3:7] = (math.cos(pose.yaw / 2), 0.0, 0.0, math.sin(pose.yaw / 2))
        self.data.qvel[:] = 0.0
        self.data.ctrl[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.odometry = WheelOdometry(self.robot.wheel_radius, self.robot.wheel_separation)
        self._update_odometry(0.0)

    # ------------------------------------------------------------ sensing

    def lidar_frame(self, lidar: int = 0) -> LidarFrame:
        """Every beam cast now, at one instant (time_increment 0); `run` sweeps instead."""
        mount = self.lidar_mounts[lidar]
        origin, rotation = self.lidar_pose(lidar)
        distances, _ = self._lidar_fan.cast(self.model, self.data, origin, rotation)
        profile = self.lidar_profile
        noise = self.config.lidar_noise if self.config.noise else None
        ranges = lidar_ranges(distances, profile, noise, self._lidar_rngs[lidar])
        stamp = self.stamp_ns
        scan = Scan(
            angle_min=profile.angle_min,
            angle_max=profile.angle_max,
            angle_increment=profile.angle_increment,
            range_min=profile.range_min,
            range_max=profile.range_max,
            ranges=ranges,
            scan_time=1.0 / profile.rate,
            frame_id=mount.frame,
            stamp_ns=stamp,
        )
        heading = math.atan2(rotation[1, 0], rotation[0, 0])
        truth = scan.with_ranges(self.truth.scan(float(origin[0]), float(origin[1]), heading))
        return LidarFrame(
            stamp,
            scan,
            truth,
            self.true_pose(),
            (float(origin[0]), float(origin[1]), float(origin[2])),
            source=mount.source,
            heading=heading,
        )

    def _start_sweep(self, lidar: int = 0) -> _Sweep:
        origin, rotation = self.lidar_pose(lidar)
        return _Sweep(
            lidar,
            self.stamp_ns,
            self.true_pose(),
            (float(origin[0]), float(origin[1]), float(origin[2])),
            math.atan2(rotation[1, 0], rotation[0, 0]),
            np.full(self.lidar_profile.count, np.nan),
        )

    def _cast_chunk(self, sweep: _Sweep, index: int) -> None:
        fan, beams = self._lidar_chunks[index]
        origin, rotation = self.lidar_pose(sweep.lidar)
        distances, _ = fan.cast(self.model, self.data, origin, rotation)
        sweep.distances[beams] = distances

    def _finish_sweep(self, sweep: _Sweep) -> LidarFrame:
        profile = self.lidar_profile
        mount = self.lidar_mounts[sweep.lidar]
        noise = self.config.lidar_noise if self.config.noise else None
        ranges = lidar_ranges(sweep.distances, profile, noise, self._lidar_rngs[sweep.lidar])
        scan = Scan(
            angle_min=profile.angle_min,
            angle_max=profile.angle_max,
            angle_increment=profile.angle_increment,
            range_min=profile.range_min,
            range_max=profile.range_max,
            ranges=ranges,
            time_increment=self.lidar_time_increment,
            scan_time=1.0 / profile.rate,
            frame_id=mount.frame,
            stamp_ns=sweep.stamp_ns,
        )
        x, y, _ = sweep.origin
        # The truth is one instant's: the stamp's, with no sweep time.
        truth = scan.with_ranges(self.truth.scan(x, y, sweep.heading), time_increment=0.0)
        return LidarFrame(
            sweep.stamp_ns,
            scan,
            truth,
            sweep.pose,
            sweep.origin,
            self.stamp_ns,
            source=mount.source,
            heading=sweep.heading,
        )

    def true_depth(self, camera: int = 0) -> npt.NDArray[np.float64]:
        """Depth along the optical axis of every pixel, metres, NaN where nothing is hit."""
        renderer = self._renderers[camera]
        if renderer is not None:
            return renderer.depth(self.data)
        origin, rotation = self.camera_pose(camera)
        distances, _ = self._depth_fan.cast(self.model, self.data, origin, rotation)
        return distances.reshape(self.camera.height, self.camera.width) * self._z_of_ray

    def depth_frame(self, camera: int = 0) -> DepthFrame:
        noise = self.config.depth_noise if self.config.noise else None
        rng = self._depth_rngs[camera]
        image = depth_image(self.true_depth(camera), self.camera_profile, noise, rng)
        source = self.camera_mounts[camera].source
        return DepthFrame(self.stamp_ns, image, self.cameras[camera], source=source)

    def cloud_pose(self) -> tuple[Matrix, Matrix]:
        """Origin and rotation (sensor -> world) of the 3D LiDAR."""
        mount = self.cloud_mount
        if mount is None:
            msg = f'the {self.robot.name} robot carries no 3D LiDAR'
            raise SimError(msg)
        position, rotation = self.base_pose()
        offset = np.array([mount.x, mount.y, mount.z])
        return position + rotation @ offset, rotation @ yaw_matrix(mount.yaw)

    def cloud_frame(self, latency_ns: int = 0) -> CloudFrame:
        """The 3D LiDAR's points now, in its frame; delivered `latency_ns` later."""
        origin, rotation = self.cloud_pose()
        assert self._cloud_fan is not None  # cloud_pose has checked the mount
        assert self.cloud_mount is not None
        distances, _ = self._cloud_fan.cast(self.model, self.data, origin, rotation)
        points = cloud_points(
            distances,
            self._cloud_directions,
            self.cloud_profile,
            self.config.noise,
            self._cloud_rng,
        )
        mount = self.cloud_mount
        stamp = self.stamp_ns
        return CloudFrame(stamp, points, mount.frame, mount.source, stamp + latency_ns)

    def contacts(self) -> list[Contact]:
        """Contacts between the robot and anything but the floor, now."""
        found = []
        stamp = self.stamp_ns
        for index in range(self.data.ncon):
            contact = self.data.contact[index]
            pair = (int(contact.geom1), int(contact.geom2))
            robot = [g for g in pair if self._robot_geoms[g]]
            other = [g for g in pair if not self._robot_geoms[g] and not self._floor[g]]
            if robot and other:
                found.append(
                    Contact(
                        stamp,
                        (float(contact.pos[0]), float(contact.pos[1]), float(contact.pos[2])),
                        self._geom_names[robot[0]],
                        self._geom_names[other[0]],
                        self.geom_kind(other[0]),
                    )
                )
        return found

    def base_drop(self) -> float:
        """How far the base is below where it settled, above the ground under it, metres."""
        x, y, z = (float(value) for value in self.data.xpos[self._body])
        ground = float(self.world.surface_height(np.array([x]), np.array([y]))[0])
        return self._rest_z + ground - z

    def imu(self) -> ImuSample:
        """The IMU's reading now (noise `SimConfig.imu_noise` when `noise` is on)."""
        w, x, y, z = (float(value) for value in self.data.xquat[self._body])
        gyro = np.array(self.data.sensordata[self._gyro : self._gyro + 3], dtype=np.float64)
        accel = np.array(
            self.data.sensordata[self._accelerometer : self._accelerometer + 3], dtype=np.float64
        )
        if self.config.noise:
            noise = self.config.imu_noise
            rng = self._imu_rng
            tilt = rng.normal(0.0, noise.orientation, 3)
            half = np.linalg.norm(tilt) / 2
            axis = tilt / (2 * half) if half > 0.0 else np.zeros(3)
            # q * dq: a small rotation about base_link's own axes.
            dw, (dx, dy, dz) = math.cos(half), math.sin(half) * axis
            w, x, y, z = (
                w * dw - x * dx - y * dy - z * dz,
                w * dx + x * dw + y * dz - z * dy,
                w * dy - x * dz + y * dw + z * dx,
                w * dz + x * dy - y * dx + z * dw,
            )
            gyro += rng.normal(0.0, noise.angular_velocity, 3)
            accel += rng.normal(0.0, noise.linear_acceleration, 3)
        return ImuSample(
            self.stamp_ns,
            (x, y, z, w),
            (float(gyro[0]), float(gyro[1]), float(gyro[2])),
            (float(accel[0]), float(accel[1]), float(accel[2])),
        )

    def check_fall(self) -> bool:
        """Whether the base has left the floor plane (now or before); records the first time."""
        if self.fell_ns is None and self.base_drop() > FALL_DEPTH:
            self.fell_ns = self.stamp_ns
        return self.fell_ns is not None

    def state(self) -> StateSample:
        position = self.data.xpos[self._body]
        w, x, y, z = (float(value) for value in self.data.xquat[self._body])
        return StateSample(
            self.stamp_ns,
            self.odometry.pose,
            self.odometry.v,
            self.odometry.omega,
            (float(position[0]), float(position[1]), float(position[2])),
            (x, y, z, w),
        )

    # ------------------------------------------------------------ time

    def _settle(self) -> None:
        """Let the robot sink onto its wheels, then restart the clock and the odometry."""
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_step(self.model, self.data, nstep=round(SETTLE_TIME / self.config.physics_step))
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        self.data.time = 0.0
        self._step = 0
        self.data.qvel[:] = 0.0
        self._update_odometry(0.0)
        x, y, z = (float(value) for value in self.data.xpos[self._body])
        self._rest_z = z - float(self.world.surface_height(np.array([x]), np.array([y]))[0])

    def _update_odometry(self, dt: float) -> None:
        self.odometry.update(
            float(self.data.qpos[self._wheels[0]]), float(self.data.qpos[self._wheels[1]]), dt
        )

    def advance(self, until: float) -> None:
        """Step the physics to time `until` (seconds, up to the next step), integrating odometry."""
        self.advance_to_step(math.ceil(until / self.config.physics_step - 1e-6))

    def advance_to_step(self, step: int) -> None:
        """Step the physics until `step` steps have passed since time zero."""
        steps = step - self._step
        if steps > 0:
            mujoco.mj_step(self.model, self.data, nstep=steps)
            # mj_step leaves the body and camera poses of the state before its last
            # integration: bring them to the new joint positions the odometry reads, so that
            # every sensor, the truth and the odometry describe the same instant.
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_camlight(self.model, self.data)
            self._step = step
            self._update_odometry(steps * self.config.physics_step)

    def run(
        self,
        duration: float,
        controller: Controller | None,
        sink: Sink,
        progress: Progress | None = None,
        *,
        stop: Callable[[], bool] | None = None,
    ) -> None:
        """Drive for `duration` seconds, every sensor at its own rate (module docstring).

        The sink gets every event that happens within the duration, in time order: a
        scan or image only once it is delivered. The controller, if any, is asked for
        (v, omega) at every delivered scan; without one the sink may steer
        (`set_command`). `stop` is asked after every event and ends the run when true.
        """
        if not duration > 0.0:
            msg = f'duration must be positive, got {duration} s'
            raise SimError(msg)
        dt = self.config.physics_step
        start = self._step
        end = start + math.floor(duration / dt + 1e-6)
        report = progress or NullProgress()
        report.start(f'simulating {self.world.name}', duration)
        reported = [self.time]
        events: list[tuple[int, int, int, Callable[[], None]]] = []
        order = itertools.count()

        def at(step: int, priority: int, action: Callable[[], None]) -> None:
            if step <= end:
                heapq.heappush(events, (step, priority, next(order), action))

        def step_of(seconds: float) -> int:
            return start + round(seconds / dt)

        def state(index: int) -> None:
            self.check_fall()
            sink.on_state(self.state())
            contacts = self.contacts()
            if contacts:
                sink.on_contacts(self.stamp_ns, contacts)
            report.advance(self.time - reported[0])
            reported[0] = self.time
            at(step_of((index + 1) / self.config.state_rate), _STATE, lambda: state(index + 1))

        latest: list[DepthFrame] = []
        latency = round(self.config.depth_latency / dt)
        stagger = self.config.sensor_stagger

        def expose(camera: int, index: int) -> None:
            frame = self.depth_frame(camera)
            delivered = replace(frame, delivered_ns=frame.stamp_ns + latency * self._step_ns)
            at(self._step + latency, _DELIVER_DEPTH, lambda: deliver_depth(camera, delivered))
            schedule_exposure(camera, index + 1)

        def deliver_depth(camera: int, frame: DepthFrame) -> None:
            if camera == 0:
                latest[:] = [frame]
            sink.on_depth(frame)

        def schedule_exposure(camera: int, index: int) -> None:
            phase = self.config.depth_phase + camera * stagger / self.depth_rate
            step = step_of(phase + index / self.depth_rate)
            if step + latency <= end:  # an image delivered after the run is not taken
                at(step, _EXPOSE, lambda: expose(camera, index))

        period = 1.0 / self.lidar_profile.rate
        increment = self.lidar_time_increment
        chunk_offsets = [
            round(0.5 * (beams[0] + beams[-1]) * increment / dt) for _, beams in self._lidar_chunks
        ]

        def sweep(lidar: int, index: int) -> None:
            current = self._start_sweep(lidar)
            for chunk, offset in enumerate(chunk_offsets):
                at(self._step + offset, _BEAMS, functools.partial(self._cast_chunk, current, chunk))
            at(self._step + round(period / dt), _DELIVER_SCAN, lambda: deliver_scan(current))
            schedule_sweep(lidar, index + 1)

        def deliver_scan(current: _Sweep) -> None:
            frame = self._finish_sweep(current)
            sink.on_lidar(frame)
            if controller is not None and current.lidar == 0:
                depth = latest[0].depth if latest else None
                observation = Observation(
                    self.time, frame.scan, depth, self.camera, self.odometry.pose
                )
                self.set_command(*controller(observation))

        def schedule_sweep(lidar: int, index: int) -> None:
            step = step_of(self.config.lidar_phase + (lidar * stagger + index) * period)
            if step + round(period / dt) <= end:  # a sweep delivered after the run is not cast
                at(step, _SWEEP, lambda: sweep(lidar, index))

        cloud_period = 1.0 / self.cloud_profile.rate
        cloud_latency = round(self.cloud_profile.latency / dt)

        def cast_cloud(index: int) -> None:
            frame = self.cloud_frame(cloud_latency * self._step_ns)
            at(self._step + cloud_latency, _DELIVER_DEPTH, lambda: sink.on_cloud(frame))
            schedule_cloud(index + 1)

        def schedule_cloud(index: int) -> None:
            step = step_of((0.25 + index) * cloud_period)
            if step + cloud_latency <= end:
                at(step, _EXPOSE, lambda: cast_cloud(index))

        def imu(index: int) -> None:
            sink.on_imu(self.imu())
            at(step_of((index + 1) / self.config.imu_rate), _IMU, lambda: imu(index + 1))

        at(start, _STATE, lambda: state(0))
        if self.config.imu_rate > 0.0:
            at(start, _IMU, lambda: imu(0))
        if self.cloud_mount is not None:
            schedule_cloud(0)
        for camera in range(len(self.camera_mounts)):
            schedule_exposure(camera, 0)
        for lidar in range(len(self.lidar_mounts)):
            schedule_sweep(lidar, 0)
        try:
            while events:
                step, _, _, action = heapq.heappop(events)
                self.advance_to_step(step)
                action()
                if stop is not None and stop():
                    return
            self.advance_to_step(end)
        finally:
            report.finish()

    def close(self) -> None:
        for renderer in self._renderers:
            if renderer is not None:
                renderer.close()
