"""Closed-loop terrain trials (issue 25): ramps, a ledge beside a ramp, door sills, braking hard
before a low box, and a camera mounted otherwise than its parameters say.

Every trial drives the `sprung` robot (`scanfuse.sim.robot.SPRUNG`: its body pitches about
3 degrees braking hard, as much setting off, and rocks over a ramp's foot and crest), with
an IMU on /imu. Families, each with seeded variants (box heights 6-12 cm above the ground
under them, shifts of a few centimetres, `worlds.ramp_world`):

- `terrain-ramp-12`, `terrain-ramp-8`: up a 1:12 (1:8) ramp to a platform 0.15 m high and down
  again, between walls, past low boxes on the ramp, on the platform and beside the ramp's
  mouth, to a goal past its far foot: the robot must get up the ramp;
- `terrain-ledge`: a 1:8 ramp whose right side is a ledge (the floor beside it missing, a yard
  0.4 m down), the robot starting right of the ramp's centre line: the straight line to the
  goal crosses the yard;
- `terrain-sills`: three rooms joined by doors with bevelled sills 1-2 cm high (drivable);
- `terrain-brake`: no planner: the robot drives straight at 0.35 m/s towards a low box across
  its path and brakes as hard as its motors allow once the driving method's scan shows
  anything within `BRAKE_TRIGGER` of its front in its path (a collision monitor's stop
  zone); on a flat floor (even seeds) or on a 1:12 ramp's platform, the box on the centre
  line (odd seeds). It counts as reached when it stopped short of the box by no more than
  `BRAKE_GAP` (a stop farther away was a stop for nothing);
- `terrain-mount`: the 1:12 ramp with the camera mounted 2 degrees and 3 cm off what the
  parameters (and /tf_static) say, the four signs in turn (seeded).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.evaluate.closed_loop import (
    AFTER_CONTACT,
    DriveLog,
    StreamFeed,
    TrialOutcome,
    TrialSpec,
    Watcher,
    log_start_ns,
    peak_pitch,
)
from scanfuse.sim.robot import SPRUNG, RobotSpec
from scanfuse.sim.worlds import (
    ROBOT_AT_ORIGIN,
    World,
    box_on_ground,
    ramp_ledge_world,
    ramp_world,
    room_walls,
    sills_world,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from scanfuse.evaluate.methods import MethodStream
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import LidarFrame, Simulation

TERRAIN_TIME_LIMIT = 45.0  # simulated seconds: about 7 m over a ramp at up to 0.35 m/s
TERRAIN_METHODS = ('lidar', 'obstacle', 'obstacle-no-ground')  # they drive the trials
# Scored on the terrain scans: the drivers, the instantaneous scan, the paper's low row and
# depthimage_to_laserscan.
TERRAIN_SCORED = ('lidar', 'row-low', 'd2l', 'obstacle', 'obstacle-no-ground', 'obstacle-no-memory')
BRAKE_SPEED = 0.35  # m/s, the navigator's cruising speed
BRAKE_TRIGGER = 0.35  # metres ahead of the footprint's front, in its path, that stop it
BRAKE_GAP = 0.6  # metres: a stop farther than this short of the box was for nothing
BRAKE_HOLD = 2.0  # seconds the run goes on after the brake
BRAKE_TIME_LIMIT = 20.0
MOUNT_PITCH_ERROR = math.radians(2.0)
MOUNT_HEIGHT_ERROR = 0.03
GOAL_PAST_RAMP = 1.1  # metres past the down ramp's foot


@dataclass(frozen=True)
class TerrainTrial:
    """One terrain trial: the world, the goal (world frame), how it is driven, and how far the
    simulated camera is from the mounting its parameters give (pitch radians, positive looks
    further down; height metres)."""

    world: World
    goal: tuple[float, float]
    brake: bool = False
    box_face: float = math.nan  # brake trials: x of the box's near face (world, metres)
    pitch_error: float = 0.0
    height_error: float = 0.0

    def robots(self, base: RobotSpec = SPRUNG) -> tuple[RobotSpec, RobotSpec]:
        """(the robot as simulated, the robot as its parameters and /tf_static describe it)."""
        simulated = replace(
            base,
            camera_pitch=base.camera_pitch + self.pitch_error,
            camera_height=base.camera_height + self.height_error,
        )
        return simulated, base


def _past_ramp(world: World, y: float = 0.0) -> tuple[float, float]:
    end = max(piece.rectangle[1] for piece in world.ground)
    return end + GOAL_PAST_RAMP, y


def _ramp12(seed: int) -> TerrainTrial:
    world = ramp_world(seed, grade=12.0)
    return TerrainTrial(world, _past_ramp(world))


def _ramp8(seed: int) -> TerrainTrial:
    world = ramp_world(seed, grade=8.0)
    return TerrainTrial(world, _past_ramp(world))


def _ledge(seed: int) -> TerrainTrial:
    world = ramp_ledge_world(seed)
    return TerrainTrial(world, _past_ramp(world, world.start.y))


def _sills(seed: int) -> TerrainTrial:
    return TerrainTrial(sills_world(seed), (4.9, 0.0))


def brake_world(seed: int = 0) -> World:
    """A flat corridor 2 m wide with a low box (0.3 m deep, 0.5 m wide, 6-12 cm) across the
    robot's path 2.4-3.2 m ahead (seeded)."""
    rng = np.random.default_rng(seed + 14000)
    bounds = (-1.0, 5.0, -1.0, 1.0)
    x = float(rng.uniform(2.55, 3.35))
    y = float(rng.uniform(-0.05, 0.05))
    height = float(rng.uniform(0.06, 0.12))
    obstacles = [*room_walls(bounds), box_on_ground('box_ahead', (), (x, y), (0.15, 0.25), height)]
    return World('brake', seed, tuple(obstacles), ROBOT_AT_ORIGIN, bounds)


def _brake(seed: int) -> TerrainTrial:
    world = ramp_world(seed, grade=12.0, blocked=True) if seed % 2 else brake_world(seed)
    name = 'box_on_platform' if seed % 2 else 'box_ahead'
    box = next(o for o in world.obstacles if o.name == name)
    face = float(box.footprint[:, 0].min())
    goal = (face - SPRUNG.body_radius - BRAKE_GAP / 2, 0.0)
    return TerrainTrial(world, goal, brake=True, box_face=face)


def _mount(seed: int) -> TerrainTrial:
    world = ramp_world(seed, grade=12.0)
    pitch_sign = 1.0 if seed % 2 == 0 else -1.0
    height_sign = -1.0 if (seed // 2) % 2 == 0 else 1.0
    return TerrainTrial(
        world,
        _past_ramp(world),
        pitch_error=pitch_sign * MOUNT_PITCH_ERROR,
        height_error=height_sign * MOUNT_HEIGHT_ERROR,
    )


TERRAIN_FAMILIES: dict[str, Callable[[int], TerrainTrial]] = {
    'terrain-ramp-12': _ramp12,
    'terrain-ramp-8': _ramp8,
    'terrain-ledge': _ledge,
    'terrain-sills': _sills,
    'terrain-brake': _brake,
    'terrain-mount': _mount,
}
# The families whose goal lies past a ramp: the robot must get up it (and down again).
RAMP_FAMILIES = ('terrain-ramp-12', 'terrain-ramp-8', 'terrain-ledge', 'terrain-mount')


def terrain_trial(name: str, seed: int) -> TerrainTrial:
    """The seeded variant `seed` of one terrain family."""
    return TERRAIN_FAMILIES[name](seed)


def terrain_specs(families: Sequence[str], variants: int) -> list[TrialSpec]:
    """`variants` seeded trials of each terrain family, family by family."""
    specs = []
    for name in families:
        for seed in range(variants):
            trial = terrain_trial(name, seed)
            limit = BRAKE_TIME_LIMIT if trial.brake else TERRAIN_TIME_LIMIT
            specs.append(TrialSpec(name, seed, trial.goal, limit))
    return specs


Released = Callable[['MethodStream', 'LidarFrame', 'Scan'], None]


def brake(
    sim: Simulation,
    trial: TrialSpec,
    box_face: float,
    driver: MethodStream,
    *,
    observers: Sequence[MethodStream] = (),
    watchers: Sequence[Watcher] = (),
    on_scan: Released | None = None,
) -> tuple[TrialOutcome, DriveLog]:
    """Drive straight at `BRAKE_SPEED` and brake hard once the driver's scan shows anything in
    the robot's path within `BRAKE_TRIGGER` of its front; stop `BRAKE_HOLD` s later."""
    robot = sim.robot
    radius = robot.body_radius
    braked: list[int] = []

    def released(stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
        if on_scan is not None:
            on_scan(stream, frame, scan)
        if stream is not driver or braked:
            return
        if _in_path(scan, robot.lidar_x, robot.lidar_y, robot.lidar_yaw, radius):
            braked.append(sim.stamp_ns)
            sim.set_command(0.0, 0.0)

    feed = StreamFeed([driver, *observers], released, watchers)
    log = feed.log

    def stop() -> bool:
        if braked and sim.stamp_ns >= braked[0] + round(BRAKE_HOLD * 1e9):
            return True
        return bool(log.contacts) and sim.stamp_ns >= log.contacts[0].stamp_ns + round(
            AFTER_CONTACT * 1e9
        )

    sim.set_command(BRAKE_SPEED, 0.0)
    sim.run(trial.time_limit, None, feed, stop=stop)
    sim.set_command(0.0, 0.0)
    feed.finish()
    first = log.contacts[0] if log.contacts else None
    final = sim.true_pose()
    gap = box_face - (final.x + radius)
    driven = np.asarray(log.true_path)
    travelled = float(np.hypot(*np.diff(driven, axis=0).T).sum()) if len(driven) > 1 else 0.0
    start = log_start_ns(sim)
    outcome = TrialOutcome(
        trial=trial.label,
        method=driver.name,
        collided=first is not None,
        first_contact_kind=first.kind if first else '',
        first_contact_time=(first.stamp_ns - start) / 1e9 if first else math.nan,
        reached=bool(braked) and first is None and 0.0 <= gap <= BRAKE_GAP,
        final_distance=gap,
        path_length=travelled,
        duration=sim.time,
        planned_length=math.nan,
        fell=sim.fell_ns is not None,
        fall_time=(sim.fell_ns - start) / 1e9 if sim.fell_ns is not None else math.nan,
        peak_pitch=peak_pitch(log.imu),
    )
    return outcome, log


def _in_path(scan: Scan, lidar_x: float, lidar_y: float, lidar_yaw: float, radius: float) -> bool:
    """Whether a reading lies in the footprint's path within `BRAKE_TRIGGER` of its front."""
    ranges = scan.ranges.astype(np.float64)
    usable = np.isfinite(ranges)
    angles: npt.NDArray[np.float64] = scan.angles()[usable] + lidar_yaw
    near = np.maximum(ranges[usable], 0.0)
    x = lidar_x + near * np.cos(angles)
    y = lidar_y + near * np.sin(angles)
    ahead = (x > 0.0) & (np.abs(y) <= radius)
    gap = x - np.sqrt(np.maximum(radius**2 - y**2, 0.0))
    return bool(np.any(ahead & (gap <= BRAKE_TRIGGER)))
