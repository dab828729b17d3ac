"""The differential-drive robot: MJCF, sensor mounting and wheel odometry.

The body frame of the robot is `base_link` (REP-105): on the floor between the
wheels, x forward, y left, z up. Every robot geom is in geom group 3, which the
ray casts exclude, so the sensors never see the robot itself.

Two robots (`ROBOTS`): `default`, round, one 360-degree LiDAR and one front depth camera;
`amr`, a box-shaped warehouse AMR with two 270-degree LiDARs at opposite corners (front-left
facing forward-left, rear-right facing backward-right, both at the default LiDAR's height,
above the low obstacles), a front and a rear depth camera and a 3D LiDAR on a mast
(PointCloud2), named and on the topics of examples/scanfuse_multi.yaml; `sprung`, the default
robot on a suspension (`Suspension`): its body sits on a sprung pitch hinge over a running
gear whose drive wheels ride on preloaded springs, so the body pitches nose-down when it
brakes, nose-up when it sets off, and rocks over a ramp's foot and a sill, as a real robot's
does (1.5-3 degrees braking hard from its cruising speed).

Every robot carries an IMU at base_link's origin (site `robot/imu`: MuJoCo's gyro and
accelerometer there; the orientation is the base's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scanfuse.sim.errors import SimError
from scanfuse.sim.worlds import Pose2D

ROBOT_GEOM_GROUP = 3
ROBOT_BODY = 'robot'
# The base has left the floor plane once it is this much below where it settled, metres:
# far above what the wheels sink into the floor or rock on the casters (millimetres), far
# below any step a robot can fall down (a stair rises 0.15-0.20 m).
FALL_DEPTH = 0.05


@dataclass(frozen=True)
class Mount:
    """Where an extra sensor sits: x, y in base_link (metres), yaw (radians, + left).

    Its height (and a camera's pitch) is the robot's `lidar_height` (`camera_height`,
    `camera_pitch`): the extra sensors are the first ones' twins.
    """

    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class LidarMount:
    """One LiDAR of a robot: its source name, frame, topic and pose in base_link."""

    source: str  # the name in a scanfuse parameter file's `lidars` ('' on the default robot)
    frame: str
    topic: str
    x: float
    y: float
    z: float
    yaw: float


@dataclass(frozen=True)
class CameraMount:
    """One depth camera of a robot: source name, frames, topics and camera_link pose."""

    source: str  # the name in `cameras` ('' on the default robot)
    frame: str  # the optical frame (REP-103: z forward, x right, y down)
    link: str  # camera_link (x forward, z up)
    depth_topic: str
    info_topic: str
    x: float
    y: float
    z: float
    yaw: float
    pitch: float


@dataclass(frozen=True)
class CloudMount:
    """A 3D LiDAR publishing PointCloud2: its source name, frame, topic and pose."""

    source: str  # the name in `clouds`
    frame: str
    topic: str
    x: float
    y: float
    z: float
    yaw: float = 0.0


@dataclass(frozen=True)
class Suspension:
    """The body on a sprung pitch hinge over the running gear (wheels and casters), the
    drive wheels on springs under the running gear.

    The hinge's axis is base_link's y axis through its origin; `stiffness` (N m/rad) and
    `damping` (N m s/rad) hold the body level, `travel` (radians) limits its pitch either way.
    Braking pitches the body nose-down on its hinge and the running gear on its wheel springs
    (its rear caster lifts): `sprung`'s numbers (tuned in MuJoCo) give about 2.8 degrees at
    the peak braking hard (the wheels' torque limit) from 0.35 m/s, about as much nose-up
    setting off (2.4 at a 2 ms physics step, whose integrator damps more); climbing a ramp it
    leans back 1-2 degrees beyond the ramp's angle. A rigid robot with two casters cannot
    climb onto a ramp: the caster ahead of the wheels rides up the ramp's foot and lifts them
    off the floor.
    """

    stiffness: float = 3000.0
    damping: float = 30.0
    travel: float = math.radians(6.0)
    # Each drive wheel on a slide along z, pressed down by a spring compressed
    # `wheel_preload` (metres) at its nominal place: 2500 N/m x 1.5 cm carries 37.5 N of each
    # wheel's ~43 N share (the casters the rest), so a caster riding 1 cm up lifts little of
    # it off and the wheels slip no more than the rigid robot's when it sets off and brakes.
    wheel_stiffness: float = 2500.0
    wheel_damping: float = 300.0
    wheel_preload: float = 0.015
    # The physics step it needs, seconds (`SimConfig.physics_step`). At 2 ms, driving straight
    # at a door sill at 0.35 m/s (the terrain trials' cruising speed), the body bounced off
    # the sill's bevel and tipped over in 2 of 15 drives (seeds 0-4, 0/8/15 degrees off
    # square); at 1 ms none of 90 did (seeds 0-9, -8/0/15 degrees, 0.2 and 0.35 m/s, and a
    # turn on the sill). At 1 ms, wheel springs of 3000 N/m (preload 1.25 cm) or wheel
    # damping of 400 N s/m tipped it over again in 10 and 3 of those 90.
    timestep: float = 0.001

    def __post_init__(self) -> None:
        if not (self.stiffness > 0.0 and self.damping >= 0.0 and 0.0 < self.travel < 0.5):
            msg = (
                f'suspension needs stiffness > 0 N m/rad, damping >= 0 N m s/rad and travel '
                f'in (0, 0.5) rad, got {self.stiffness}, {self.damping}, {self.travel}'
            )
            raise SimError(msg)
        if not 0.0 < self.timestep <= 0.01:
            msg = f'suspension timestep {self.timestep} s must be in (0, 0.01]'
            raise SimError(msg)
        wheels = (self.wheel_stiffness, self.wheel_damping, self.wheel_preload)
        if not (wheels[0] > 0.0 and wheels[1] >= 0.0 and 0.0 < wheels[2] < 0.05):
            msg = (
                f'suspension needs wheel_stiffness > 0 N/m, wheel_damping >= 0 N s/m and '
                f'wheel_preload in (0, 0.05) m, got {wheels[0]}, {wheels[1]}, {wheels[2]}'
            )
            raise SimError(msg)


IMU_SITE = 'robot/imu'
RUNNING_GEAR = 'robot/running_gear'  # a sprung robot's wheels and casters (`Suspension`)


@dataclass(frozen=True)
class RobotSpec:
    """Dimensions of the robot and where its sensors sit on it (metres, radians).

    The chassis is a cylinder as tall as the collision slab, so a thin board the
    LiDAR misses still stops it.
    """

    body_radius: float = 0.18
    body_bottom: float = 0.06
    body_top: float = 0.50
    mass: float = 8.0
    wheel_radius: float = 0.05
    wheel_separation: float = 0.30
    wheel_friction: float = 1.0
    # A caster 6 cm across rolls up a door sill's 1:2 bevel, 1-2 cm high (on 4 cm ones, before
    # each sill was one solid, the sprung robot reared up and tipped over at one sill of five).
    caster_radius: float = 0.03
    caster_offset: float = 0.13
    max_wheel_torque: float = 2.0
    max_wheel_speed: float = 20.0
    lidar_x: float = 0.0
    lidar_height: float = 0.30
    lidar_yaw: float = 0.0
    camera_x: float = 0.12
    camera_height: float = 0.45
    camera_pitch: float = math.radians(20.0)
    name: str = 'default'
    lidar_y: float = 0.0
    # Half length and half width of a box chassis (None: a cylinder of body_radius). The
    # evaluation's navigator plans for the disc of body_radius: give a box its circumradius.
    chassis: tuple[float, float] | None = None
    rear_lidar: Mount | None = None  # a second LiDAR, the first's model and height
    rear_camera: Mount | None = None  # a second depth camera, the first's model and pitch
    lidar_model: str = 'rplidar-a2'  # the LiDAR profile it carries unless told otherwise
    cloud: CloudMount | None = None  # a 3D LiDAR (PointCloud2), the `cloud` profile of SimConfig
    suspension: Suspension | None = None  # a sprung body and wheels (None: one rigid body)
    # A one-LiDAR, one-camera robot's topics: the node's defaults, or a parameter file's
    # (`scanfuse simulate --params`), so the file means the same to the recording.
    scan_topic: str = '/scan'
    depth_topic: str = '/camera/depth/image_raw'
    camera_info_topic: str = '/camera/depth/camera_info'

    def __post_init__(self) -> None:
        if not 0.0 < self.lidar_height < 3.0:
            msg = f'lidar_height {self.lidar_height} m is outside (0, 3) m'
            raise SimError(msg)
        if not 0.0 < self.camera_height < 3.0:
            msg = f'camera_height {self.camera_height} m is outside (0, 3) m'
            raise SimError(msg)
        if not -math.pi / 2 < self.camera_pitch < math.pi / 2:
            msg = f'camera_pitch {self.camera_pitch} rad must be within (-pi/2, pi/2)'
            raise SimError(msg)
        if self.chassis is not None and math.hypot(*self.chassis) > self.body_radius + 1e-9:
            msg = (
                f'a {2 * self.chassis[0]:.3g} x {2 * self.chassis[1]:.3g} m chassis reaches '
                f'beyond body_radius {self.body_radius} m; give body_radius its circumradius '
                f'{math.hypot(*self.chassis):.3f} m (the planner keeps that disc clear)'
            )
            raise SimError(msg)

    @property
    def several(self) -> bool:
        """The robot has more than one LiDAR or camera (named sources, per-sensor topics)."""
        return self.rear_lidar is not None or self.rear_camera is not None or self.cloud is not None

    def lidars(self) -> tuple[LidarMount, ...]:
        """Every LiDAR, the first (the fused scan's frame and trigger) first."""
        z = self.lidar_height
        if not self.several:
            return (
                LidarMount(
                    '', 'laser', self.scan_topic, self.lidar_x, self.lidar_y, z, self.lidar_yaw
                ),
            )
        mounts = [_named_lidar('front', self.lidar_x, self.lidar_y, self.lidar_yaw, z)]
        if self.rear_lidar is not None:
            rear = self.rear_lidar
            mounts.append(_named_lidar('rear', rear.x, rear.y, rear.yaw, z))
        return tuple(mounts)

    def cameras(self) -> tuple[CameraMount, ...]:
        """Every depth camera, the first (paired with the first LiDAR's scans) first."""
        pitch, z = self.camera_pitch, self.camera_height
        if not self.several:
            return (
                CameraMount(
                    '',
                    'camera_depth_optical_frame',
                    'camera_link',
                    self.depth_topic,
                    self.camera_info_topic,
                    self.camera_x,
                    0.0,
                    z,
                    0.0,
                    pitch,
                ),
            )
        mounts = [_named_camera('front', self.camera_x, 0.0, 0.0, z, pitch)]
        if self.rear_camera is not None:
            rear = self.rear_camera
            mounts.append(_named_camera('rear', rear.x, rear.y, rear.yaw, z, pitch))
        return tuple(mounts)

    def wheel_speeds(self, v: float, omega: float) -> tuple[float, float]:
        """Left and right wheel speeds (rad/s) for body speeds v (m/s) and omega (rad/s)."""
        half = self.wheel_separation / 2
        return (v - omega * half) / self.wheel_radius, (v + omega * half) / self.wheel_radius

    def mjcf(self, start: Pose2D, mounted: str = '') -> str:
        """The robot body with a free joint, placed at `start`; `mounted` (MJCF: the cameras)
        goes into the body that carries the sensors (base_link)."""
        group = ROBOT_GEOM_GROUP
        half_height = (self.body_top - self.body_bottom) / 2
        r = self.wheel_radius
        y = self.wheel_separation / 2
        spring = self.suspension
        # Each wheel is a tyre 24 mm wide with a rounded profile (an ellipsoid): it touches
        # the floor at one patch. A cylinder touches it at its two rim edges, which turn at
        # different radii about the robot's centre and scrub against each other in a turn.
        # A sprung robot's wheels slide along z, pressed down by a preloaded spring: they
        # keep their grip when a caster rides up a ramp's foot ahead of them.
        wheel_spring = (
            ''
            if spring is None
            else f'<joint name="{{side}}_wheel_spring" type="slide" axis="0 0 1" '
            f'stiffness="{spring.wheel_stiffness:.6g}" damping="{spring.wheel_damping:.6g}" '
            f'springref="{-spring.wheel_preload:.6g}" '
            f'range="{-2 * spring.wheel_preload:.6g} {spring.wheel_preload:.6g}" limited="true"/>'
        )
        wheels = ''.join(
            f'<body name="robot/{side}_wheel" pos="0 {sign * y:.6g} {r:.6g}">'
            f'{wheel_spring.format(side=side)}'
            f'<joint name="{side}_wheel" type="hinge" axis="0 1 0" damping="0.01"/>'
            f'<geom name="robot/{side}_wheel" type="ellipsoid" size="{r:.6g} {r:.6g} 0.012" '
            f'euler="1.5707963267948966 0 0" mass="0.3" '
            f'friction="{self.wheel_friction:.6g} 0.005 0.0001" '
            f'group="{group}" rgba="0.1 0.1 0.1 1"/></body>'
            for side, sign in (('left', 1.0), ('right', -1.0))
        )
        casters = ''.join(
            f'<geom name="robot/caster_{name}" type="sphere" size="{self.caster_radius:.6g}" '
            f'pos="{sign * self.caster_offset:.6g} 0 {self.caster_radius:.6g}" mass="0.05" '
            f'condim="1" priority="1" friction="0 0 0" group="{group}"/>'
            for name, sign in (('front', 1.0), ('back', -1.0))
        )
        if self.chassis is None:
            shape = f'type="cylinder" size="{self.body_radius:.6g} {half_height:.6g}"'
        else:
            shape = (
                f'type="box" size="{self.chassis[0]:.6g} {self.chassis[1]:.6g} {half_height:.6g}"'
            )
        body = (
            f'<geom name="robot/chassis" {shape} pos="0 0 {self.body_bottom + half_height:.6g}" '
            f'mass="{self.mass:.6g}" group="{group}" rgba="0.2 0.4 0.8 1"/>'
            f'<site name="{IMU_SITE}" pos="0 0 0" size="0.01" group="{group}"/>{mounted}'
        )
        place = f'pos="{start.x:.6g} {start.y:.6g} 0" euler="0 0 {start.yaw:.9g}"'
        if spring is None:
            return (
                f'<body name="{ROBOT_BODY}" {place}><freejoint name="robot_root"/>'
                f'{body}{casters}{wheels}</body>'
            )
        # The wheels and casters ride on a running gear; the body (base_link, with every
        # sensor) sits on it on a pitch hinge through base_link's origin, held by a spring.
        return (
            f'<body name="{RUNNING_GEAR}" {place}><freejoint name="robot_root"/>{casters}{wheels}'
            f'<body name="{ROBOT_BODY}" pos="0 0 0">'
            f'<joint name="suspension" type="hinge" axis="0 1 0" '
            f'stiffness="{spring.stiffness:.6g}" damping="{spring.damping:.6g}" '
            f'range="{-spring.travel:.6g} {spring.travel:.6g}" limited="true"/>'
            f'{body}</body></body>'
        )

    def contact_mjcf(self) -> str:
        """Pairs that never collide: a sprung body and the wheels beside it on the running
        gear (a body and its own wheels are parent and child, excluded already)."""
        if self.suspension is None:
            return ''
        return ''.join(
            f'<exclude body1="{ROBOT_BODY}" body2="robot/{side}_wheel"/>'
            for side in ('left', 'right')
        )

    def sensors_mjcf(self) -> str:
        """The IMU's gyro and accelerometer at base_link's origin (`IMU_SITE`)."""
        return (
            f'<gyro name="imu_gyro" site="{IMU_SITE}"/>'
            f'<accelerometer name="imu_accelerometer" site="{IMU_SITE}"/>'
        )

    def actuators_mjcf(self) -> str:
        """Velocity servos on both wheels; the torque limit lets the wheels slip when blocked."""
        limit = self.max_wheel_torque
        speed = self.max_wheel_speed
        return ''.join(
            f'<velocity name="{side}_wheel" joint="{side}_wheel" kv="1.0" '
            f'ctrlrange="{-speed:.6g} {speed:.6g}" forcerange="{-limit:.6g} {limit:.6g}" '
            'forcelimited="true"/>'
            for side in ('left', 'right')
        )


def _named_lidar(name: str, x: float, y: float, yaw: float, z: float) -> LidarMount:
    """A LiDAR named as examples/scanfuse_multi.yaml names it (`front`, ...)."""
    return LidarMount(name, f'{name}_laser', f'/{name}/scan', x, y, z, yaw)


def _named_camera(name: str, x: float, y: float, yaw: float, z: float, pitch: float) -> CameraMount:
    """A camera named as examples/scanfuse_multi.yaml names it (`front_depth`, ...)."""
    return CameraMount(
        f'{name}_depth',
        f'{name}_camera_depth_optical_frame',
        f'{name}_camera_link',
        f'/{name}_camera/depth/image_rect_raw',
        f'/{name}_camera/depth/camera_info',
        x,
        y,
        z,
        yaw,
        pitch,
    )


# The AMR's box chassis, half length and half width (metres): 0.5 m x 0.34 m.
AMR_CHASSIS = (0.25, 0.17)
AMR = RobotSpec(
    name='amr',
    lidar_model='hokuyo-ust10lx',
    body_radius=math.hypot(*AMR_CHASSIS),
    chassis=AMR_CHASSIS,
    mass=14.0,
    wheel_separation=0.34,
    caster_offset=0.20,
    max_wheel_torque=3.0,
    # Front-left corner, facing forward-left; rear-right corner, facing backward-right:
    # each 270-degree field of view covers the two faces beside its corner.
    lidar_x=AMR_CHASSIS[0],
    lidar_y=AMR_CHASSIS[1],
    lidar_yaw=math.pi / 4,
    rear_lidar=Mount(-AMR_CHASSIS[0], -AMR_CHASSIS[1], -3 * math.pi / 4),
    camera_x=AMR_CHASSIS[0],
    rear_camera=Mount(-AMR_CHASSIS[0], 0.0, math.pi),
    # On a mast, 1.1 m up: it sees what stands above the robot's height.
    cloud=CloudMount('livox', 'livox_frame', '/livox/points', 0.0, 0.0, 1.1),
)
# The default robot on sprung casters (`Suspension`): its body pitches with acceleration.
SPRUNG = RobotSpec(name='sprung', suspension=Suspension())
ROBOTS: dict[str, RobotSpec] = {'default': RobotSpec(), 'amr': AMR, 'sprung': SPRUNG}


def robot_spec(name: str) -> RobotSpec:
    """The robot called `name` (one of `ROBOTS`)."""
    spec = ROBOTS.get(name)
    if spec is None:
        msg = f'unknown robot {name!r}; choose one of {", ".join(ROBOTS)}'
        raise SimError(msg)
    return spec


@dataclass
class WheelOdometry:
    """Pose integrated from the wheel joint angles alone, as a real robot's odometry.

    It knows the nominal wheel radius and separation and nothing else, so when a
    wheel slips (the robot pushes against an obstacle) the estimate drifts.
    """

    wheel_radius: float
    wheel_separation: float
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    v: float = 0.0
    omega: float = 0.0
    _last: tuple[float, float] | None = None

    def update(self, left_angle: float, right_angle: float, dt: float) -> None:
        """Integrate the motion since the last call (midpoint heading: second-order on arcs)."""
        if self._last is None:
            self._last = (left_angle, right_angle)
            return
        d_left = (left_angle - self._last[0]) * self.wheel_radius
        d_right = (right_angle - self._last[1]) * self.wheel_radius
        self._last = (left_angle, right_angle)
        distance = (d_left + d_right) / 2
        turn = (d_right - d_left) / self.wheel_separation
        heading = self.yaw + turn / 2
        self.x += distance * math.cos(heading)
        self.y += distance * math.sin(heading)
        self.yaw = math.atan2(math.sin(self.yaw + turn), math.cos(self.yaw + turn))
        if dt > 0.0:
            self.v, self.omega = distance / dt, turn / dt

    @property
    def pose(self) -> Pose2D:
        return Pose2D(self.x, self.y, self.yaw)
