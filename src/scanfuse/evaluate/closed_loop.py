"""Closed-loop trials: the robot drives to a goal behind obstacles with what a method's scan shows.

The navigator knows what a real Nav2 robot knows: its wheel odometry, the scan the
method gives it, and where it is on the map. It keeps a Nav2-like obstacle layer
(`costmap.Costmap`: marking, and raytrace clearing that erases what a later ray passes
over) in the odometry frame, each scan at the odometry pose of its stamp (as a costmap
looks the scan up in TF), plans with A* on it inflated by its radius, follows the path,
and a stop/slow zone on the current scan guards its front. Its goal and waypoints are on
the map (the world frame), brought into the odometry frame at every step through the
map -> odom transform a localizer (AMCL, slam_toolbox) publishes, exact here
(`map_to_odom`): wheel odometry drifts (slipping at a sill, on a ramp, in a turn), and a
robot's goal does not drift with it. Whether it collides is
decided by MuJoCo's contacts, whether it fell by its base leaving the floor plane
(`Simulation.check_fall`), whether it arrived by its true pose.

The simulator runs in real sensor time (`Simulation.run`) and `StreamFeed` hands every
event to each method's `FusionStream` as the node would receive it: odometry at 50 Hz,
depth images and CameraInfo at their delivery, scans at the end of their sweep. The
navigator steps on every scan the driving method's stream releases, when it releases it.
Turning trials (`TURNING_TRIALS`) drive a scripted turn past low obstacles instead.

A trial may ask for its first waypoints to be reached backwards (`reverse_waypoints`: the
AMR backing out of a dead end): the navigator follows the same A* path rear first, its
stop/slow zones turned round to guard the rear, and a trial records whether its first
contact came while reversing.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from scanfuse.evaluate.costmap import Costmap
from scanfuse.evaluate.mapping import GridSpec
from scanfuse.evaluate.memory_trials import MEMORY_FAMILIES, memory_trial
from scanfuse.evaluate.planner import SafetyZones, astar, disk_offsets, inflate, path_length
from scanfuse.motion import OdometryHistory, PlanarPose
from scanfuse.sim.drive import Arc, Rotate
from scanfuse.sim.sensors import OPTICAL_FRAME
from scanfuse.sim.worlds import (
    ROBOT_AT_ORIGIN,
    SMALL_ROOM,
    Pose2D,
    World,
    bookshelf,
    floor_lamp,
    low_box,
    make_world,
    room_walls,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from scanfuse.evaluate.methods import MethodStream
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import (
        CloudFrame,
        Contact,
        Controller,
        DepthFrame,
        ImuSample,
        LidarFrame,
        Simulation,
        StateSample,
    )

LOW_KINDS = ('low_box', 'lamp_base', 'cable_tray')
CLOSED_LOOP_TIME_LIMIT = 45.0


@dataclass(frozen=True)
class TrialSpec:
    """One closed-loop run: a world, its seed, and the goal (world frame, metres)."""

    world: str
    seed: int
    goal: tuple[float, float]
    time_limit: float = 45.0  # simulated seconds
    waypoints: tuple[tuple[float, float], ...] = ()  # passed in order before the goal
    reverse_waypoints: int = 0  # the first this many waypoints are reached backwards

    @property
    def memory(self) -> bool:
        """A trial where obstacle memory matters (`memory_trials`)."""
        return self.world in MEMORY_FAMILIES

    @property
    def label(self) -> str:
        return f'{self.world}-{self.seed}'


# Goals behind the paper's two obstacles: straight through the bookshelf's boards,
# and past the barricade where its top leaves room and its base does not.
# In the drop worlds the straight line from the start to the goal crosses the drop (0.45 m
# into the ledge's yard; through the middle of the stairwell and of the hole), and the
# floor around it leads there: the walkway north of the ledge, 0.9-1.4 m beside the others.
FIXED_GOALS = {
    'bookshelf': (2.8, 0.0),
    'barricade': (2.5, 0.6),
    'room': (2.0, 1.5),
    'ledge': (4.0, 1.2),
    'stairs': (3.4, 0.0),
    'hole': (3.2, 0.0),
}
SHELF_DISTANCE = 2.0
ROOM_BEHIND_SHELF = 1.3  # metres from the shelf's front to the wall behind it


def evaluation_world(name: str, seed: int) -> World:
    """The simulator's world, except that the bookshelf stands 1 m clear of the wall behind.

    The simulator's bookshelf world leaves 0.5 m behind the shelf, too narrow for
    the robot to reach a goal there, so the goal could not lie "behind" the boards.
    The memory families are `memory_trials`' worlds.
    """
    if name in MEMORY_FAMILIES:
        return memory_trial(name, seed).world
    if name != 'bookshelf':
        return make_world(name, seed)
    bounds = (SMALL_ROOM[0], SHELF_DISTANCE + ROOM_BEHIND_SHELF, SMALL_ROOM[2], SMALL_ROOM[3])
    obstacles = room_walls(bounds) + bookshelf('shelf', SHELF_DISTANCE, 0.0)
    return World('bookshelf', seed, tuple(obstacles), ROBOT_AT_ORIGIN, bounds)


GOAL_BEYOND = 0.7  # metres past the obstacle a clutter goal lies, on the line from the start


def clutter_goal(world: World) -> tuple[float, float]:
    """A goal just behind one low obstacle of the world, as seen from the start (seeded)."""
    rng = np.random.default_rng(world.seed + 1000)
    start = np.array([world.start.x, world.start.y])
    low = [o for o in world.obstacles if o.kind in LOW_KINDS]
    x_min, x_max, y_min, y_max = world.bounds
    for index in rng.permutation(len(low)):
        centre = low[index].footprint.mean(axis=0)
        direction = centre - start
        goal = centre + GOAL_BEYOND * direction / np.linalg.norm(direction)
        inside = x_min + 0.4 < goal[0] < x_max - 0.4 and y_min + 0.4 < goal[1] < y_max - 0.4
        if inside and _clear_of(world, goal, 0.35):
            return float(goal[0]), float(goal[1])
    return x_max - 0.6, 0.0


def _clear_of(world: World, point: npt.NDArray[np.float64], clearance: float) -> bool:
    for obstacle in world.obstacles:
        if obstacle.kind == 'wall':
            continue
        if np.min(np.hypot(*(obstacle.footprint - point).T)) < clearance:
            return False
        footprint = obstacle.footprint
        lo, hi = footprint.min(axis=0), footprint.max(axis=0)
        if np.all(point >= lo) and np.all(point <= hi):
            return False
    return True


def trial_specs(worlds: list[str], clutter_trials: int, time_limit: float) -> list[TrialSpec]:
    """bookshelf, barricade (and room) once each; `clutter_trials` seeded clutter worlds."""
    specs = [
        TrialSpec(name, 0, FIXED_GOALS[name], time_limit) for name in worlds if name in FIXED_GOALS
    ]
    if 'clutter' in worlds:
        for seed in range(clutter_trials):
            goal = clutter_goal(make_world('clutter', seed))
            specs.append(TrialSpec('clutter', seed, goal, time_limit))
    return specs


MEMORY_TIME_LIMIT = 40.0  # simulated seconds: the shelf's round trip is about 6 m


def memory_specs(families: Sequence[str], variants: int) -> list[TrialSpec]:
    """`variants` seeded trials of each memory family, family by family."""
    specs = []
    for name in families:
        for seed in range(variants):
            trial = memory_trial(name, seed)
            specs.append(TrialSpec(name, seed, trial.goal, MEMORY_TIME_LIMIT, trial.waypoints))
    return specs


def world_to_odom(start: Pose2D, x: float, y: float) -> tuple[float, float]:
    """A world point in the odometry frame, which starts at the robot's start pose."""
    c, s = math.cos(start.yaw), math.sin(start.yaw)
    dx, dy = x - start.x, y - start.y
    return c * dx + s * dy, -s * dx + c * dy


def map_to_odom(
    true_pose: Pose2D, odometry: Pose2D
) -> Callable[[float, float], tuple[float, float]]:
    """World (map) point -> odometry frame, with the robot at `true_pose` on the map and at
    `odometry` in the odometry frame: the transform a localizer publishes as map -> odom."""
    robot_in_map = PlanarPose(true_pose.x, true_pose.y, true_pose.yaw)
    odom_from_map = PlanarPose(odometry.x, odometry.y, odometry.yaw).compose(robot_in_map.inverse())

    def to_odom(x: float, y: float) -> tuple[float, float]:
        point = odom_from_map.compose(PlanarPose(x, y, 0.0))
        return point.x, point.y

    return to_odom


def odom_to_world(start: Pose2D, pose: Pose2D) -> Pose2D:
    c, s = math.cos(start.yaw), math.sin(start.yaw)
    return Pose2D(
        start.x + c * pose.x - s * pose.y, start.y + s * pose.x + c * pose.y, start.yaw + pose.yaw
    )


@dataclass
class Navigator:
    """Plans on what the scans showed and drives there; `step` is called once per scan."""

    spec: GridSpec
    goal: tuple[float, float]  # odometry frame
    radius: float
    lidar_x: float = 0.0
    waypoints: list[tuple[float, float]] = field(default_factory=list)  # odometry frame
    lidar_y: float = 0.0  # the scan's frame in base_link: x, y (metres), yaw (radians)
    lidar_yaw: float = 0.0
    # The first this many waypoints are reached driving backwards (backing out of a dead
    # end): the path is followed rear first and the stop/slow zones guard the rear.
    reverse_waypoints: int = 0
    reverse_speed: float = 0.25
    waypoint_tolerance: float = 0.3
    max_speed: float = 0.35
    max_turn: float = 1.2
    inflation_margin: float = 0.06
    clear_margin: float = 0.16  # > stop zone (0.08) + a cell's half diagonal (0.035)
    lookahead: float = 0.35
    goal_tolerance: float = 0.2
    mark_range: float = 2.5  # the collision monitor's zones look at returns this near
    replan_every: int = 10
    zones: SafetyZones = field(init=False)
    costmap: Costmap = field(init=False)
    path: list[tuple[float, float]] = field(default_factory=list)
    done: bool = False
    last_v: float = 0.0  # the speed last commanded, m/s (negative: reversing)
    _steps: int = 0

    def __post_init__(self) -> None:
        self.zones = SafetyZones(self.radius)
        self.costmap = Costmap(self.spec)

    @property
    def reversing(self) -> bool:
        """Heading for a waypoint that is reached backwards."""
        return self.reverse_waypoints > 0 and bool(self.waypoints)

    def step(
        self, scan: Scan, pose: Pose2D, scan_pose: Pose2D | None = None
    ) -> tuple[float, float]:
        """(v, omega) for the scan just received, with the robot at `pose` (odometry frame)
        now and at `scan_pose` (default `pose`) at the scan's stamp."""
        v, omega = self._step(scan, pose, scan_pose)
        self.last_v = v
        return v, omega

    def _step(self, scan: Scan, pose: Pose2D, scan_pose: Pose2D | None) -> tuple[float, float]:
        points = self._points_in_robot(scan)
        at = scan_pose or pose
        c, s = math.cos(at.yaw), math.sin(at.yaw)
        self.costmap.update(
            scan,
            at.x + c * self.lidar_x - s * self.lidar_y,
            at.y + s * self.lidar_x + c * self.lidar_y,
            at.yaw + self.lidar_yaw,
        )
        self.costmap.clear_disk(pose.x, pose.y, self.radius)
        if self.waypoints and (
            math.hypot(self.waypoints[0][0] - pose.x, self.waypoints[0][1] - pose.y)
            <= self.waypoint_tolerance
        ):
            self.waypoints.pop(0)
            self.reverse_waypoints = max(0, self.reverse_waypoints - 1)
            self.path = []
        heading = self.target()
        to_goal = math.hypot(heading[0] - pose.x, heading[1] - pose.y)
        if to_goal <= self.goal_tolerance and not self.waypoints:
            self.done = True
            return 0.0, 0.0
        if not self.path or self._steps % self.replan_every == 0 or self._path_blocked():
            self._plan(pose)
        self._steps += 1
        if not self.path:
            return 0.0, 0.4  # nothing known leads there: turn and look
        target = self._target(pose)
        reversing = self.reversing
        # Backwards, the rear leads: steer the rear towards the target, guard the rear.
        facing = pose.yaw + math.pi if reversing else pose.yaw
        error = math.atan2(target[1] - pose.y, target[0] - pose.x) - facing
        error = math.atan2(math.sin(error), math.cos(error))
        omega = max(-self.max_turn, min(self.max_turn, 2.0 * error))
        speed = self.reverse_speed if reversing else self.max_speed
        v = speed * max(0.0, math.cos(error)) ** 4 if abs(error) < 0.8 else 0.0
        if not self.waypoints:
            v = min(v, 0.8 * to_goal + 0.05)
        if reversing:
            return -self.zones.limit(v, -points), omega
        return self.zones.limit(v, points), omega

    def target(self) -> tuple[float, float]:
        """Where the robot is heading: the next waypoint, or the goal."""
        return self.waypoints[0] if self.waypoints else self.goal

    def planned_length(self) -> float:
        """Length of the current plan, metres (NaN: no plan)."""
        if not self.path:
            return float('nan')
        return path_length([self._cell(x, y) for x, y in self.path], self.spec.resolution)

    def blocked(self) -> npt.NDArray[np.bool_]:
        return self.costmap.lethal

    def _points_in_robot(self, scan: Scan) -> npt.NDArray[np.float64]:
        ranges = scan.ranges.astype(np.float64)
        usable = np.isfinite(ranges) & (ranges <= self.mark_range)
        angles = scan.angles()[usable] + self.lidar_yaw
        near = np.maximum(ranges[usable], 0.0)
        return np.column_stack(
            [self.lidar_x + near * np.cos(angles), self.lidar_y + near * np.sin(angles)]
        )

    def _plan(self, pose: Pose2D) -> None:
        # A path kept clear of the stop zone first (as Nav2's inflation cost keeps plans off
        # obstacles): a plan that grazes an obstacle has the zone stop the robot on it for
        # good. Only where none exists, the tight one.
        for margin in (self.clear_margin, self.inflation_margin):
            self._plan_with(pose, margin)
            if self.path:
                return

    def _plan_with(self, pose: Pose2D, margin: float) -> None:
        raw = self.blocked()
        reach = (self.radius + margin) / self.spec.resolution
        blocked = inflate(raw, reach)
        start = self._cell(pose.x, pose.y)
        # The robot may stand inside the inflation (it cut a corner): let the plan lead it
        # out through cells that only inflation blocks.
        height, width = raw.shape
        for dy, dx in disk_offsets(reach):
            row, column = start[0] + dy, start[1] + dx
            if 0 <= row < height and 0 <= column < width:
                blocked[row, column] = raw[row, column]
        goal = self._free_goal(blocked)
        cells = astar(blocked, start, goal) if goal is not None else None
        self.path = [] if cells is None else [self._centre(cell) for cell in cells]

    def _free_goal(self, blocked: npt.NDArray[np.bool_]) -> tuple[int, int] | None:
        """The goal cell, or the free cell nearest to it within the goal tolerance."""
        goal = self._cell(*self.target())
        if not blocked[goal]:
            return goal
        reach = math.ceil(self.goal_tolerance / self.spec.resolution)
        best: tuple[float, tuple[int, int]] | None = None
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                row, column = goal[0] + dy, goal[1] + dx
                inside = 0 <= row < self.spec.height and 0 <= column < self.spec.width
                if inside and not blocked[row, column] and dx * dx + dy * dy <= reach * reach:
                    distance = math.hypot(dx, dy)
                    if best is None or distance < best[0]:
                        best = (distance, (row, column))
        return None if best is None else best[1]

    def _path_blocked(self) -> bool:
        if not self.path:
            return False
        blocked = self.blocked()
        for x, y in self.path[:: max(1, len(self.path) // 40)]:
            row, column = self._cell(x, y)
            if blocked[row, column]:
                return True
        return False

    def _target(self, pose: Pose2D) -> tuple[float, float]:
        path = np.asarray(self.path)
        distance = np.hypot(path[:, 0] - pose.x, path[:, 1] - pose.y)
        nearest = int(np.argmin(distance))
        ahead = np.nonzero(distance[nearest:] >= self.lookahead)[0]
        index = nearest + int(ahead[0]) if ahead.size else len(self.path) - 1
        return self.path[index]

    def _cell(self, x: float, y: float) -> tuple[int, int]:
        column, row, _ = self.spec.cell_of(np.array([x]), np.array([y]))
        return (
            int(np.clip(row[0], 0, self.spec.height - 1)),
            int(np.clip(column[0], 0, self.spec.width - 1)),
        )

    def _centre(self, cell: tuple[int, int]) -> tuple[float, float]:
        row, column = cell
        return (
            self.spec.origin[0] + (column + 0.5) * self.spec.resolution,
            self.spec.origin[1] + (row + 0.5) * self.spec.resolution,
        )


@dataclass(frozen=True)
class FrameRecord:
    """What one scan the navigator drove on leaves for the evaluation."""

    lidar: LidarFrame
    odometry: Pose2D  # odometry frame, at the scan's stamp
    used: Scan  # the scan the navigator drove on


@dataclass(frozen=True)
class TrialOutcome:
    """How one closed-loop trial went."""

    trial: str
    method: str
    collided: bool
    first_contact_kind: str
    first_contact_time: float
    reached: bool
    final_distance: float  # true distance to the goal at the end, metres
    path_length: float  # true distance driven, metres
    duration: float  # simulated seconds
    planned_length: float  # length of the last plan, metres
    fell: bool = False  # the base left the floor plane (a drop-off)
    fall_time: float = float('nan')  # simulated seconds at the first fallen state sample
    reversing_contact: bool = False  # the first contact came while driving backwards
    peak_pitch: float = float('nan')  # degrees: the largest |pitch| the IMU measured


@dataclass
class DriveLog:
    """Everything a trial produced: per-frame records (when kept), contacts, true poses."""

    frames: list[FrameRecord] = field(default_factory=list)
    contacts: list[Contact] = field(default_factory=list)
    true_path: list[tuple[float, float]] = field(default_factory=list)
    imu: list[ImuSample] = field(default_factory=list)


Released = Callable[['MethodStream', 'LidarFrame', 'Scan'], None]


class Watcher(Protocol):
    """Fed the simulator's events as a stream is, before the streams; releases nothing
    (the evaluation's record of what the camera showed)."""

    def add_state(self, sample: StateSample) -> None: ...

    def add_depth(self, frame: DepthFrame) -> None: ...


@dataclass
class StreamFeed:
    """A simulation sink that feeds every method's stream as the node is fed, in time order.

    `released` gets each scan a stream releases (the stream, the simulator's frame, the
    scan to use). The feed also keeps the contacts, the true path and the odometry.
    """

    streams: Sequence[MethodStream]
    released: Released
    watchers: Sequence[Watcher] = ()
    log: DriveLog = field(default_factory=DriveLog)
    odometry: OdometryHistory = field(default_factory=OdometryHistory)

    def _emit(self, stream: MethodStream, outputs: list[tuple[LidarFrame, Scan]]) -> None:
        for frame, scan in outputs:
            self.released(stream, frame, scan)

    def on_state(self, sample: StateSample) -> None:
        self.log.true_path.append((sample.position[0], sample.position[1]))
        odometry = sample.odometry
        self.odometry.add(sample.stamp_ns, PlanarPose(odometry.x, odometry.y, odometry.yaw))
        for watcher in self.watchers:
            watcher.add_state(sample)
        for stream in self.streams:
            self._emit(stream, stream.add_state(sample))

    def on_depth(self, frame: DepthFrame) -> None:
        for watcher in self.watchers:
            watcher.add_depth(frame)
        for stream in self.streams:
            self._emit(stream, stream.add_depth(frame, frame.camera.frame_id or OPTICAL_FRAME))

    def on_lidar(self, frame: LidarFrame) -> None:
        for stream in self.streams:
            self._emit(stream, stream.add_scan(frame))

    def on_cloud(self, frame: CloudFrame) -> None:
        for stream in self.streams:
            self._emit(stream, stream.add_cloud(frame))

    def on_contacts(self, stamp_ns: int, contacts: list[Contact]) -> None:
        del stamp_ns  # every contact carries its own stamp
        self.log.contacts.extend(contacts)

    def on_imu(self, sample: ImuSample) -> None:
        """The IMU's samples: kept (`DriveLog.imu`) and given to every stream."""
        self.log.imu.append(sample)
        for stream in self.streams:
            stream.add_imu(sample)

    def finish(self) -> None:
        for stream in self.streams:
            self._emit(stream, stream.finish())

    def odometry_at(self, stamp_ns: int) -> Pose2D | None:
        found = self.odometry.pose_at(stamp_ns).pose
        return None if found is None else Pose2D(found.x, found.y, found.yaw)


AFTER_CONTACT = 3.0  # seconds the run goes on after the first contact (the wheels slip)
AFTER_FALL = 1.0  # seconds the run goes on after a fall (the robot comes to rest below)


def drive(
    sim: Simulation,
    trial: TrialSpec,
    driver: MethodStream,
    *,
    observers: Sequence[MethodStream] = (),
    watchers: Sequence[Watcher] = (),
    on_scan: Released | None = None,
    keep_frames: bool = False,
) -> tuple[TrialOutcome, DriveLog]:
    """Run one closed-loop trial driving on what `driver` releases, in real sensor time.

    `observers` are fed the same events (scoring, maps), `watchers` too and before them;
    `on_scan` sees every scan any stream releases.
    """
    world = sim.world
    goal = world_to_odom(world.start, *trial.goal)
    bounds = world.bounds
    corners = [world_to_odom(world.start, x, y) for x in bounds[:2] for y in bounds[2:]]
    xs, ys = zip(*corners, strict=True)
    spec = GridSpec.covering((min(xs), max(xs), min(ys), max(ys)), 0.05, margin=0.3)
    navigator = Navigator(
        spec,
        goal,
        sim.robot.body_radius,
        lidar_x=sim.robot.lidar_x,
        waypoints=[world_to_odom(world.start, *point) for point in trial.waypoints],
        lidar_y=sim.robot.lidar_y,
        lidar_yaw=sim.robot.lidar_yaw,
        reverse_waypoints=trial.reverse_waypoints,
    )
    # The command in force when the first contact was found (negative: reversing).
    contact_v: list[float] = []

    def released(stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
        if on_scan is not None:
            on_scan(stream, frame, scan)
        if stream is not driver or navigator.done:
            return
        now = sim.odometry.pose
        believed = feed.odometry_at(frame.stamp_ns) or now
        if keep_frames:
            feed.log.frames.append(FrameRecord(frame, believed, scan))
        to_odom = map_to_odom(sim.true_pose(), now)
        navigator.goal = to_odom(*trial.goal)
        ahead = trial.waypoints[len(trial.waypoints) - len(navigator.waypoints) :]
        navigator.waypoints = [to_odom(*point) for point in ahead]
        sim.set_command(*navigator.step(scan, now, believed))

    feed = StreamFeed([driver, *observers], released, watchers)
    log = feed.log

    def stop() -> bool:
        if log.contacts and not contact_v:
            contact_v.append(navigator.last_v)
        if navigator.done:
            return True
        if sim.fell_ns is not None and sim.stamp_ns >= sim.fell_ns + round(AFTER_FALL * 1e9):
            return True
        return bool(log.contacts) and sim.stamp_ns >= log.contacts[0].stamp_ns + round(
            AFTER_CONTACT * 1e9
        )

    sim.run(trial.time_limit, None, feed, stop=stop)
    sim.set_command(0.0, 0.0)
    feed.finish()
    first_contact = log.contacts[0] if log.contacts else None
    final = sim.true_pose()
    distance = math.hypot(final.x - trial.goal[0], final.y - trial.goal[1])
    driven = np.asarray(log.true_path)
    travelled = float(np.hypot(*np.diff(driven, axis=0).T).sum()) if len(driven) > 1 else 0.0
    outcome = TrialOutcome(
        trial=trial.label,
        method=driver.name,
        collided=first_contact is not None,
        first_contact_kind=first_contact.kind if first_contact else '',
        first_contact_time=(
            (first_contact.stamp_ns - log_start_ns(sim)) / 1e9 if first_contact else float('nan')
        ),
        reached=distance <= GOAL_REACHED and sim.fell_ns is None,
        final_distance=distance,
        path_length=travelled,
        duration=sim.time,
        planned_length=navigator.planned_length(),
        fell=sim.fell_ns is not None,
        fall_time=(
            (sim.fell_ns - log_start_ns(sim)) / 1e9 if sim.fell_ns is not None else float('nan')
        ),
        reversing_contact=bool(contact_v) and contact_v[0] < 0.0,
        peak_pitch=peak_pitch(log.imu),
    )
    return outcome, log


def peak_pitch(samples: Sequence[ImuSample]) -> float:
    """The largest |pitch| the IMU measured, degrees (NaN without samples)."""
    if not samples:
        return math.nan
    return math.degrees(max(abs(sample.roll_pitch[1]) for sample in samples))


# ---------------------------------------------------------------- turning trials


@dataclass(frozen=True)
class TurningSpec:
    """A scripted turn past low obstacles: scan metrics only (no method steers it)."""

    label: str
    duration: float  # simulated seconds
    make_controller: Callable[[], Controller]
    description: str


TURN_RATE = 1.5  # rad/s, turning in place
ARC_SPEED, ARC_RATE = 0.4, 0.8  # m/s and rad/s: a 0.5 m radius arc to the left
TURNING_BOUNDS = (-1.6, 2.2, -1.6, 2.2)


def turning_world(seed: int = 0) -> World:
    """Four low obstacles and a lamp around the robot at the origin, clear of both turns.

    The arc (radius 0.5 m about (0, 0.5)) passes 0.46-0.92 m from the obstacles' centres;
    turning in place, each is 1.0-1.4 m away.
    """
    obstacles = room_walls(TURNING_BOUNDS)
    obstacles.append(low_box('box_ahead', (1.0, -0.1), 0.3, (0.3, 0.2, 0.10)))
    obstacles.append(low_box('box_left', (0.95, 0.8), -0.4, (0.2, 0.2, 0.06)))
    obstacles.append(low_box('box_behind', (-0.9, -0.6), 0.8, (0.35, 0.2, 0.12)))
    obstacles += floor_lamp('lamp', (-0.6, 1.25))
    return World('turning', seed, tuple(obstacles), ROBOT_AT_ORIGIN, TURNING_BOUNDS)


TURNING_TRIALS: dict[str, TurningSpec] = {
    spec.label: spec
    for spec in (
        TurningSpec(
            'turn-in-place',
            5.0,
            lambda: Rotate(TURN_RATE),
            f'turn in place at {TURN_RATE} rad/s beside low boxes and a lamp',
        ),
        TurningSpec(
            'arc',
            6.0,
            lambda: Arc(ARC_SPEED, ARC_RATE),
            f'an arc of radius {ARC_SPEED / ARC_RATE:.1f} m at {ARC_SPEED} m/s and '
            f'{ARC_RATE} rad/s past low boxes and a lamp',
        ),
    )
}


def turn(
    sim: Simulation,
    spec: TurningSpec,
    streams: Sequence[MethodStream],
    on_scan: Released,
    watchers: Sequence[Watcher] = (),
) -> DriveLog:
    """Run one scripted turning trial, every stream fed in real sensor time."""
    feed = StreamFeed(streams, on_scan, watchers)
    sim.run(spec.duration, spec.make_controller(), feed)
    sim.set_command(0.0, 0.0)
    feed.finish()
    return feed.log


GOAL_REACHED = 0.3  # metres between the true pose and the goal that count as arrived


def log_start_ns(sim: Simulation) -> int:
    """The stamp of simulated time zero."""
    return sim.stamp_ns - round(sim.time * 1e9)
