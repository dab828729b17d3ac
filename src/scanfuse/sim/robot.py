"""The differential-drive robot: MJCF, sensor mounting and wheel odometry.

The body frame of the robot is `base_link` (REP-105): on the floor between the
wheels, x forward, y left, z up. Every robot geom is in geom group 3, which the
ray casts exclude, so the sensors never see the robot itself.
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
    caster_radius: float = 0.02
    caster_offset: float = 0.13
    max_wheel_torque: float = 2.0
    max_wheel_speed: float = 20.0
    lidar_x: float = 0.0
    lidar_height: float = 0.30
    lidar_yaw: float = 0.0
    camera_x: float = 0.12
    camera_height: float = 0.45
    camera_pitch: float = math.radians(20.0)

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

    def wheel_speeds(self, v: float, omega: float) -> tuple[float, float]:
        """Left and right wheel speeds (rad/s) for body speeds v (m/s) and omega (rad/s)."""
        half = self.wheel_separation / 2
        return (v - omega * half) / self.wheel_radius, (v + omega * half) / self.wheel_radius

    def mjcf(self, start: Pose2D) -> str:
        """The robot body with a free joint, placed at `start`."""
        group = ROBOT_GEOM_GROUP
        half_height = (self.body_top - self.body_bottom) / 2
        r = self.wheel_radius
        y = self.wheel_separation / 2
        wheels = ''.join(
            f'<body name="robot/{side}_wheel" pos="0 {sign * y:.6g} {r:.6g}">'
            f'<joint name="{side}_wheel" type="hinge" axis="0 1 0" damping="0.01"/>'
            f'<geom name="robot/{side}_wheel" type="cylinder" size="{r:.6g} 0.012" '
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
        return (
            f'<body name="{ROBOT_BODY}" pos="{start.x:.6g} {start.y:.6g} 0" '
            f'euler="0 0 {start.yaw:.9g}">'
            '<freejoint name="robot_root"/>'
            f'<geom name="robot/chassis" type="cylinder" size="{self.body_radius:.6g} '
            f'{half_height:.6g}" pos="0 0 {self.body_bottom + half_height:.6g}" '
            f'mass="{self.mass:.6g}" group="{group}" rgba="0.2 0.4 0.8 1"/>'
            f'{casters}{wheels}</body>'
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
