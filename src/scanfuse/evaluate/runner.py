"""`evaluate`: closed-loop trials, scan metrics, maps and figures for every method.

Steps: run every trial with every closed-loop method; during the `obstacle` runs
(the robot drives safely, so the scans cover the approach to each obstacle) feed
every method's own `FusionStream` the same sensor events and score each scan it
releases against the ground truth at the scan's stamp, and build each method's map;
run the scripted turning trials the same way; keep a few frames for the figures;
run the two-LiDAR, two-camera AMR's trials (`amr_trials`: backing out of a dead end past a
low box) with its own methods, scored on the `obstacle` runs' 360-degree fused scans; run the
terrain trials (`terrain_trials`: ramps, a ledge beside a ramp, sills, hard braking, a camera
mounted off its parameters, the sprung robot) with their methods, scored on the `obstacle`
runs apart from the other worlds (all their scans, and those on or near a ramp); write
results. All of it in real sensor time (`scanfuse.sim.simulation`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

from scanfuse.cluster import Backend, LocalPool, backend_of, run_tasks
from scanfuse.evaluate.amr_trials import (
    AMR_FAMILIES,
    AMR_LIDAR,
    AMR_METHODS,
    AMR_TIME_LIMIT,
    amr_trial,
)
from scanfuse.evaluate.attribution import SOURCES, count_sources
from scanfuse.evaluate.closed_loop import (
    CLOSED_LOOP_TIME_LIMIT,
    TURNING_TRIALS,
    DriveLog,
    TrialOutcome,
    TrialSpec,
    TurningSpec,
    Watcher,
    drive,
    evaluation_world,
    memory_specs,
    odom_to_world,
    trial_specs,
    turn,
    turning_world,
)
from scanfuse.evaluate.costmap import Costmap
from scanfuse.evaluate.drops import DropTally, false_drop_slots, reports_drops
from scanfuse.evaluate.groundtruth import SeenSurfaces, SlotTruthBuilder
from scanfuse.evaluate.mapping import (
    GridSpec,
    OccupancyGrid,
    compare_maps,
    rasterize_footprints,
)
from scanfuse.evaluate.memory_trials import MEMORY_FAMILIES
from scanfuse.evaluate.methods import CLOSED_LOOP_METHODS, METHODS, MethodStream, method_spec
from scanfuse.evaluate.metrics import ScanMetrics, ScanTally, false_obstacle_slots
from scanfuse.evaluate.results import (
    ClosedLoopSummary,
    EvaluationResult,
    MethodResult,
    RobotResult,
    TerrainResult,
)
from scanfuse.evaluate.terrain_trials import (
    TERRAIN_FAMILIES,
    TERRAIN_METHODS,
    TERRAIN_SCORED,
    brake,
    terrain_specs,
    terrain_trial,
)
from scanfuse.motion import OdometryHistory, PlanarPose
from scanfuse.progress import NullProgress, Progress
from scanfuse.transforms import Extrinsics, Transform

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    import numpy as np
    import numpy.typing as npt

    from scanfuse.config import FusionConfig
    from scanfuse.frames import StampedTransform
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import (
        DepthFrame,
        LidarFrame,
        SimConfig,
        Simulation,
        StateSample,
    )
    from scanfuse.sim.worlds import World

MAP_RESOLUTION = 0.05
DROPS_OFF = '(detect_drops off)'  # a twin stream's label in the scorer
FIGURE_DISTANCE = 1.0  # metres from the robot to the obstacle's front in the scan figures


@dataclass(frozen=True)
class EvaluationSettings:
    """What an evaluation runs; `quick()` is the small version for tests and the demo."""

    worlds: tuple[str, ...] = (
        'bookshelf',
        'barricade',
        'clutter',
        'ledge',
        'stairs',
        'hole',
        'memory',
        'terrain',
    )
    trials: int = 30  # seeded clutter worlds
    methods: tuple[str, ...] = tuple(METHODS)
    closed_loop_methods: tuple[str, ...] = CLOSED_LOOP_METHODS
    resolution: tuple[int, int] = (424, 240)
    time_limit: float = CLOSED_LOOP_TIME_LIMIT
    noise: bool = True
    map_resolution: float = MAP_RESOLUTION
    mapped_trials: int = 3  # first trials whose frames are mapped per method
    turning: tuple[str, ...] = tuple(TURNING_TRIALS)  # scripted turning trials
    memory: tuple[str, ...] = tuple(MEMORY_FAMILIES)  # closed-loop memory families
    memory_trials: int = 15  # seeded variants per memory family
    # Sensor timing (the LiDAR's rate is its profile's, odometry 50 Hz): see the report.
    lidar: str = 'rplidar-a2'
    depth_rate: float = 15.0  # Hz
    depth_latency: float = 0.040  # seconds from exposure to delivery
    lidar_chunks: int = 12  # ray casts per sweep
    odometry_rate: float = 50.0  # Hz
    # The AMR (two 270-degree LiDARs, front and rear cameras): its families, seeded variants
    # per family, and methods (`lidar`: the LiDARs merged; `obstacle`: every source).
    amr: tuple[str, ...] = tuple(AMR_FAMILIES)
    amr_trials: int = 5
    amr_methods: tuple[str, ...] = AMR_METHODS
    # The terrain trials (world `terrain`): families, seeded variants per family, methods.
    terrain: tuple[str, ...] = tuple(TERRAIN_FAMILIES)
    terrain_trials: int = 5
    terrain_methods: tuple[str, ...] = TERRAIN_METHODS
    # Scored on the terrain trials' scans, of `methods` (each scored method runs a stream, and
    # a twin for false drops, through every trial: all of them would cost twice the time).
    terrain_scored: tuple[str, ...] = TERRAIN_SCORED
    # A parameter file's ros__parameters (`--params`): the robot's mounting and slab, and
    # the base every method's configuration changes; empty: the simulated robot as built.
    params: dict[str, Any] = field(default_factory=dict)

    def fusion_base(self) -> FusionConfig | None:
        """The configuration `params` describe (validated), or None without parameters."""
        from scanfuse.config import FusionConfig  # noqa: PLC0415

        return FusionConfig.from_dict(self.params) if self.params else None

    @classmethod
    def quick(cls, **changes: Any) -> EvaluationSettings:
        base = cls(
            worlds=('bookshelf', 'barricade', 'clutter', 'ledge', 'memory'),
            trials=2,
            closed_loop_methods=('lidar', 'obstacle', 'obstacle-no-memory'),
            memory_trials=1,
            resolution=(256, 144),
            time_limit=20.0,
            mapped_trials=3,
            amr_trials=1,
            terrain_trials=1,
        )
        return replace(base, **changes)


def base_config(sim: Simulation, settings: EvaluationSettings) -> FusionConfig:
    """The fusion configuration of the simulated robot: its mounting and camera, on top of
    the parameter file's values when there is one."""
    from scanfuse.sim.simulation import fusion_config  # noqa: PLC0415

    return fusion_config(sim.config, settings.fusion_base())


def make_simulation(trial: TrialSpec | TurningSpec, settings: EvaluationSettings) -> Simulation:
    """The trial's simulation; depth through mujoco.Renderer when a headless GL was chosen.

    With parameters, the robot is mounted and the slab set as they say (radians throughout).
    An AMR trial's robot is the AMR as built, with its own LiDARs (parameters set its slab);
    every other trial's the default robot.
    """
    from scanfuse.sim.robot import AMR, RobotSpec  # noqa: PLC0415
    from scanfuse.sim.simulation import Simulation, robot_mounting  # noqa: PLC0415

    amr = isinstance(trial, TrialSpec) and trial.world in AMR_FAMILIES
    if isinstance(trial, TurningSpec):
        world, seed = turning_world(), 0
    elif amr:
        world, seed = amr_trial(trial.world, trial.seed).world, trial.seed
    else:
        world, seed = evaluation_world(trial.world, trial.seed), trial.seed
    robot: dict[str, Any] = {'robot': AMR} if amr else {}
    base = settings.fusion_base()
    if base is not None:
        mounting: dict[str, Any] = {} if amr else dict(robot_mounting(base))
        robot = {
            'robot': AMR if amr else RobotSpec(**mounting),
            'min_obstacle_height': base.min_obstacle_height,
            'max_obstacle_height': base.max_obstacle_height,
        }
    config = sim_config(settings, world, seed, AMR_LIDAR if amr else settings.lidar, **robot)
    return Simulation(config, world)


def sim_config(
    settings: EvaluationSettings, world: World, seed: int, lidar: str, **robot: Any
) -> SimConfig:
    """The simulation's configuration: the settings' sensors and timing, `robot`'s fields."""
    from scanfuse.sim.simulation import SimConfig  # noqa: PLC0415

    return SimConfig(
        world=world.name,
        seed=seed,
        lidar=lidar,
        resolution=settings.resolution,
        depth_rate=settings.depth_rate,
        depth_latency=settings.depth_latency,
        lidar_chunks=settings.lidar_chunks,
        state_rate=settings.odometry_rate,
        noise=settings.noise,
        **robot,
    )


def terrain_simulation(
    spec: TrialSpec, settings: EvaluationSettings
) -> tuple[Simulation, FusionConfig, list[StampedTransform]]:
    """A terrain trial's simulation of the sprung robot, and the configuration and /tf_static
    of the robot as its parameters describe it (the camera's mounting errors left out)."""
    from scanfuse.sim.recording import static_transforms  # noqa: PLC0415
    from scanfuse.sim.robot import SPRUNG  # noqa: PLC0415
    from scanfuse.sim.simulation import Simulation, fusion_config, robot_mounting  # noqa: PLC0415

    trial = terrain_trial(spec.world, spec.seed)
    base = settings.fusion_base()
    slab: dict[str, Any] = {}
    robot = SPRUNG
    if base is not None:
        mounting: dict[str, Any] = dict(robot_mounting(base))
        robot = replace(SPRUNG, **mounting)
        slab = {
            'min_obstacle_height': base.min_obstacle_height,
            'max_obstacle_height': base.max_obstacle_height,
        }
    simulated, nominal = trial.robots(robot)
    config = sim_config(settings, trial.world, spec.seed, settings.lidar, robot=simulated, **slab)
    sim = Simulation(config, trial.world)
    described = fusion_config(replace(config, robot=nominal), base)
    return sim, described, static_transforms(nominal)


def robot_transforms(sim: Simulation) -> list[StampedTransform]:
    """The /tf_static a recording of this robot holds, as the node would receive it."""
    from scanfuse.sim.recording import static_transforms  # noqa: PLC0415

    return static_transforms(sim.robot)


@dataclass
class MapSet:
    """The maps one mapped trial builds: one per method (true poses) and the driving run's."""

    spec: GridSpec
    truth: npt.NDArray[np.bool_]
    grids: dict[str, OccupancyGrid] = field(default_factory=dict)

    def grid(self, name: str) -> OccupancyGrid:
        if name not in self.grids:
            self.grids[name] = OccupancyGrid(self.spec)
        return self.grids[name]


def _map_set(world: World, settings: EvaluationSettings, slab: tuple[float, float]) -> MapSet:
    spec = GridSpec.covering(world.bounds, settings.map_resolution, margin=0.3)
    polygons = [o.footprint for o in world.obstacles if o.overlaps_slab(*slab)]
    return MapSet(spec, rasterize_footprints(spec, polygons))


@dataclass
class Snapshot:
    """One frame kept for a figure, with every method's scan of it."""

    trial: str
    frame: LidarFrame
    scans: dict[str, Scan]


# (index into the trials, a turning trial's name, or 'amr:<index into the AMR trials>', method)
Job = tuple[int | str, str]
AMR_JOB = 'amr:'
TERRAIN_JOB = 'terrain:'
# Terrain scans count as on slopes when the LiDAR is on a ramp or this near one, metres.
SLOPE_REACH = 1.5


@dataclass
class EvaluationPart:
    """What one or more jobs of an evaluation measured, to merge into another `Evaluation`."""

    tallies: dict[str, ScanTally]
    world_tallies: dict[str, dict[str, ScanTally]]
    outcomes: list[TrialOutcome]
    maps: dict[str, MapSet]
    snapshots: dict[str, Snapshot]
    collision_logs: dict[str, tuple[World, DriveLog, TrialOutcome, float]]
    crash_maps: dict[str, MapSet]
    stream_counts: dict[str, dict[str, int]]
    costmaps: dict[str, CostmapSet]
    drop_tallies: dict[str, DropTally]
    amr_tallies: dict[str, ScanTally] = field(default_factory=dict)
    amr_outcomes: list[TrialOutcome] = field(default_factory=list)
    terrain: TerrainTallies | None = None


@dataclass
class TerrainTallies:
    """What the terrain trials measured: scans over all of them and on or near slopes (per
    method), false drop slots likewise, and every trial's outcome."""

    scans: dict[str, ScanTally] = field(default_factory=dict)
    slopes: dict[str, ScanTally] = field(default_factory=dict)
    drops: dict[str, DropTally] = field(default_factory=dict)
    slope_drops: dict[str, DropTally] = field(default_factory=dict)
    outcomes: list[TrialOutcome] = field(default_factory=list)
    # Per fusing method, its false obstacle slots on slopes by the source that made them
    # (`attribution.SOURCES`' order).
    slope_sources: dict[str, list[int]] = field(default_factory=dict)
    # The body's pitch over the scoring run of each family's first trial: times (s), pitch
    # (degrees, positive nose-down) from the IMU, for the report's figure.
    pitch: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)

    def add_slope_sources(self, name: str, counts: Sequence[int]) -> None:
        mine = self.slope_sources.setdefault(name, [0] * len(SOURCES))
        mine[:] = [a + b for a, b in zip(mine, counts, strict=True)]

    @classmethod
    def of(cls, methods: Sequence[str]) -> TerrainTallies:
        return cls(
            {name: ScanTally() for name in methods},
            {name: ScanTally() for name in methods},
            {name: DropTally() for name in methods},
            {name: DropTally() for name in methods},
        )

    def merge(self, other: TerrainTallies) -> None:
        for mine, theirs in ((self.scans, other.scans), (self.slopes, other.slopes)):
            for name, tally in theirs.items():
                mine[name].merge(tally)
        for mine_drops, their_drops in (
            (self.drops, other.drops),
            (self.slope_drops, other.slope_drops),
        ):
            for name, drops in their_drops.items():
                mine_drops[name].slots += drops.slots
                mine_drops[name].false_drops += drops.false_drops
        self.outcomes += other.outcomes
        for name, counts in other.slope_sources.items():
            self.add_slope_sources(name, counts)
        for label, trace in other.pitch.items():
            self.pitch.setdefault(label, trace)


@dataclass
class CostmapSet:
    """The costmap figure's trial: each method's Nav2-like costmap (true poses) and the end."""

    world: World
    costmaps: dict[str, Costmap]
    robot: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world x, y, yaw at the last scan


COSTMAP_TRIAL = 'turn-in-place'
COSTMAP_METHODS = ('obstacle', 'obstacle-no-memory', 'lidar')


def _run_job(settings: EvaluationSettings, job: Job) -> EvaluationPart:
    """One job in a worker process, in an `Evaluation` of its own."""
    from scanfuse.sim.headless_gl import choose_headless_gl  # noqa: PLC0415

    choose_headless_gl()
    evaluation = Evaluation(settings)
    evaluation.run_job(job)
    return evaluation.part()


def _check_names(kind: str, names: Iterable[str], known: Iterable[str]) -> None:
    from scanfuse.errors import ConfigError  # noqa: PLC0415

    choices = list(known)
    for name in names:
        if name not in choices:
            msg = f'unknown {kind} {name!r}; choose from {", ".join(choices)}'
            raise ConfigError(msg)


class Evaluation:
    """One evaluation run; `run()` does the work, `result()` packs it up."""

    def __init__(self, settings: EvaluationSettings, progress: Progress | None = None) -> None:
        for kind, names, known in (
            ('method', settings.closed_loop_methods, METHODS),
            ('memory trial', settings.memory, MEMORY_FAMILIES),
            ('turning trial', settings.turning, TURNING_TRIALS),
            ('AMR trial', settings.amr, AMR_FAMILIES),
            ('AMR method', settings.amr_methods, AMR_METHODS),
            ('terrain trial', settings.terrain, TERRAIN_FAMILIES),
            ('terrain method', settings.terrain_methods, METHODS),
        ):
            _check_names(kind, names, known)
        # Scored methods may have parameters changed (`method_spec`); they do not drive.
        for name in (*settings.methods, *settings.terrain_scored):
            method_spec(name)
        self.settings = settings
        self.progress: Progress = progress or NullProgress()
        self.retried = 0  # trials run again on a Ray cluster after their worker died
        self.trials = trial_specs(list(settings.worlds), settings.trials, settings.time_limit)
        if 'memory' in settings.worlds:
            self.trials += memory_specs(settings.memory, settings.memory_trials)
        self.amr_specs = amr_specs(settings.amr, settings.amr_trials)
        self.terrain_specs = (
            terrain_specs(settings.terrain, settings.terrain_trials)
            if 'terrain' in settings.worlds
            else []
        )
        self.terrain = TerrainTallies.of(settings.methods)
        base = settings.fusion_base()
        if base is not None and (self.trials or settings.turning):
            from scanfuse.sim.simulation import robot_mounting  # noqa: PLC0415

            # The default robot follows the file's mounting: one it cannot have fails here,
            # not in a trial (the AMR trials keep the AMR as built).
            robot_mounting(base)
        self.amr_tallies = {name: ScanTally() for name in settings.amr_methods}
        self.amr_outcomes: list[TrialOutcome] = []
        self.tallies = {name: ScanTally() for name in settings.methods}
        self.world_tallies: dict[str, dict[str, ScanTally]] = {}
        # False drop slots per method, over the scans of worlds without drop-offs.
        self.drop_tallies = {name: DropTally() for name in settings.methods}
        self.outcomes: list[TrialOutcome] = []
        self.maps: dict[str, MapSet] = {}
        self.snapshots: dict[str, Snapshot] = {}
        self.collision_logs: dict[str, tuple[World, DriveLog, TrialOutcome, float]] = {}
        # Maps of the LiDAR-only robot's run, from its own scans and from the fused ones.
        self.crash_maps: dict[str, MapSet] = {}
        # Per method: what its scoring streams did (scans, fused, compensated, ...).
        self.stream_counts: dict[str, dict[str, int]] = {}
        # The Nav2-like costmaps of the costmap figure's turning trial, per method.
        self.costmaps: dict[str, CostmapSet] = {}
        # The trials whose maps are kept: the first ones (each trial is scored in one run).
        self.mapped_labels = (
            {t.label for t in self.trials[: settings.mapped_trials]}
            if settings.closed_loop_methods
            else set()
        )

    def jobs(self) -> list[Job]:
        """Every trial of the run in its serial order: (trial index or turning name, method)."""
        work: list[Job] = [
            (index, method)
            for index in range(len(self.trials))
            for method in self.settings.closed_loop_methods
        ]
        work += [(name, '') for name in self.settings.turning]
        work += [
            (f'{AMR_JOB}{index}', method)
            for index in range(len(self.amr_specs))
            for method in self.settings.amr_methods
        ]
        work += [
            (f'{TERRAIN_JOB}{index}', method)
            for index in range(len(self.terrain_specs))
            for method in self.settings.terrain_methods
        ]
        return work

    def run(
        self,
        jobs: int = 1,
        *,
        backend: Backend | None = None,
        job_runner: Callable[[EvaluationSettings, Job], EvaluationPart] | None = None,
    ) -> None:
        """Run every trial; `jobs` > 1 runs them in that many processes, `backend` where it
        says (a local pool or a Ray cluster; it takes the place of `jobs`).

        Each process runs single trials into an `Evaluation` of its own; the parent merges
        their parts in the serial order, so that the result is the serial run's. `retried`
        counts the trials run again after their worker died. `job_runner` runs one job in a
        worker (`_run_job` unless a test stands in one that fails on purpose).
        """
        backend = backend or backend_of(jobs)
        work = self.jobs()
        self.progress.start('closed-loop and turning trials', len(work))
        if isinstance(backend, LocalPool) and (backend.jobs == 1 or len(work) <= 1):
            for job in work:
                self.run_job(job)
                self.progress.advance()
        else:
            if isinstance(backend, LocalPool) and job_runner is None:
                # The first job here: it compiles the kernels into numba's cache once, which
                # every worker would otherwise compile itself, at once, on the same cores.
                self.run_job(work[0])
                self.progress.advance()
                work = work[1:]
            arguments = [(self.settings, job) for job in work]
            done = run_tasks(job_runner or _run_job, arguments, backend, self.progress)
            for part in done.results:
                self.merge(part)
            self.retried += done.retried
        self.progress.finish()

    def run_job(self, job: Job) -> None:
        key, method = job
        if isinstance(key, str) and key.startswith(AMR_JOB):
            self._amr_trial(self.amr_specs[int(key[len(AMR_JOB) :])], method)
        elif isinstance(key, str) and key.startswith(TERRAIN_JOB):
            self._terrain_trial(self.terrain_specs[int(key[len(TERRAIN_JOB) :])], method)
        elif isinstance(key, str):
            self._turning(TURNING_TRIALS[key])
        else:
            self._trial(self.trials[key], method)

    def part(self) -> EvaluationPart:
        return EvaluationPart(
            self.tallies,
            self.world_tallies,
            self.outcomes,
            self.maps,
            self.snapshots,
            self.collision_logs,
            self.crash_maps,
            self.stream_counts,
            self.costmaps,
            self.drop_tallies,
            self.amr_tallies,
            self.amr_outcomes,
            self.terrain,
        )

    def merge(self, part: EvaluationPart) -> None:
        """Add one job's part, as if that job had run here next."""
        for name, tally in part.tallies.items():
            self.tallies[name].merge(tally)
        for group, tallies in part.world_tallies.items():
            mine = self.world_tallies.setdefault(
                group, {name: ScanTally() for name in self.settings.methods}
            )
            for name, tally in tallies.items():
                mine[name].merge(tally)
        self.outcomes += part.outcomes
        for label, map_set in part.maps.items():
            if label not in self.maps and len(self.maps) < self.settings.mapped_trials:
                self.maps[label] = map_set
        for label, snapshot in part.snapshots.items():
            self.snapshots.setdefault(label, snapshot)
        self.collision_logs.update(part.collision_logs)
        self.crash_maps.update(part.crash_maps)
        self.costmaps.update(part.costmaps)
        for name, drops in part.drop_tallies.items():
            self.drop_tallies[name].slots += drops.slots
            self.drop_tallies[name].false_drops += drops.false_drops
        for name, counts in part.stream_counts.items():
            total = self.stream_counts.setdefault(name, {})
            for key, value in counts.items():
                total[key] = total.get(key, 0) + value
        for name, tally in part.amr_tallies.items():
            self.amr_tallies[name].merge(tally)
        self.amr_outcomes += part.amr_outcomes
        if part.terrain is not None:
            self.terrain.merge(part.terrain)

    def _trial(self, trial: TrialSpec, method: str) -> None:
        sim = make_simulation(trial, self.settings)
        try:
            base = base_config(sim, self.settings)
            transforms = robot_transforms(sim)
            driver = MethodStream(method, base, sim.camera, transforms)
            scorer = (
                _Scorer(self, trial.label, trial.world, sim, base, transforms, mapped=True)
                if _scores(method, self.settings.closed_loop_methods)
                else None
            )
            keep = method == 'lidar' and trial.world in {'bookshelf', 'barricade'}
            # The LiDAR-only robot's run, fused as well, for the maps of what it missed.
            crash = MethodStream('obstacle', base, sim.camera, transforms) if keep else None
            crash_scans: list[tuple[LidarFrame, Scan]] = []
            observers = [*(scorer.streams if scorer else ()), *((crash,) if crash else ())]
            watchers = scorer.watchers if scorer else []

            def on_scan(stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
                if scorer is not None:
                    scorer.add(stream, frame, scan)
                if stream is crash:
                    crash_scans.append((frame, scan))

            outcome, log = drive(
                sim,
                trial,
                driver,
                observers=observers,
                watchers=watchers,
                on_scan=on_scan,
                keep_frames=keep,
            )
            if scorer is not None:
                scorer.close()
            self.outcomes.append(outcome)
            if keep:
                self.collision_logs[trial.label] = (sim.world, log, outcome, sim.robot.body_radius)
                self.crash_maps[trial.label] = self._crash_maps(sim, base, log, crash_scans)
        finally:
            sim.close()

    def _amr_trial(self, trial: TrialSpec, method: str) -> None:
        """One AMR trial driven by `method`; the `obstacle` run scores every AMR method."""
        sim = make_simulation(trial, self.settings)
        try:
            base = base_config(sim, self.settings)
            transforms = robot_transforms(sim)
            driver = MethodStream(method, base, sim.camera, transforms)
            methods = self.settings.amr_methods
            scorer = _AmrScorer(self, sim, base) if _scores(method, methods) else None
            # The driver's own scans are scored too: one stream per method.
            observers = (
                [
                    MethodStream(name, base, sim.camera, transforms)
                    for name in methods
                    if name != method
                ]
                if scorer is not None
                else []
            )
            names = {stream: stream.name for stream in (driver, *observers)}

            def on_scan(stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
                if scorer is not None and stream in names:
                    scorer.add(names[stream], frame, scan)

            outcome, _ = drive(sim, trial, driver, observers=observers, on_scan=on_scan)
            self.amr_outcomes.append(outcome)
        finally:
            sim.close()

    def _terrain_trial(self, spec: TrialSpec, method: str) -> None:
        """One terrain trial driven by `method`; the `obstacle` run scores every method.

        The streams get the robot as its parameters describe it; the simulated camera may sit
        otherwise (`TerrainTrial.pitch_error`, `height_error`). The truth's camera view is the
        simulated camera's.
        """
        trial = terrain_trial(spec.world, spec.seed)
        sim, base, transforms = terrain_simulation(spec, self.settings)
        try:
            driver = MethodStream(method, base, sim.camera, transforms)
            scorer = (
                _Scorer(
                    self,
                    spec.label,
                    spec.world,
                    sim,
                    base,
                    transforms,
                    mapped=False,
                    terrain=True,
                )
                if _scores(method, self.settings.terrain_methods)
                else None
            )
            observers = scorer.streams if scorer else []

            def on_scan(stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
                if scorer is not None:
                    scorer.add(stream, frame, scan)

            if trial.brake:
                outcome, log = brake(
                    sim, spec, trial.box_face, driver, observers=observers, on_scan=on_scan
                )
            else:
                outcome, log = drive(sim, spec, driver, observers=observers, on_scan=on_scan)
            if scorer is not None:
                scorer.close()
                if spec.seed == 0 and log.imu:
                    start = log.imu[0].stamp_ns
                    self.terrain.pitch[spec.label] = (
                        [(sample.stamp_ns - start) / 1e9 for sample in log.imu],
                        [math.degrees(sample.roll_pitch[1]) for sample in log.imu],
                    )
            self.terrain.outcomes.append(outcome)
        finally:
            sim.close()

    def _turning(self, spec: TurningSpec) -> None:
        sim = make_simulation(spec, self.settings)
        try:
            base = base_config(sim, self.settings)
            scorer = _Scorer(
                self, spec.label, spec.label, sim, base, robot_transforms(sim), mapped=False
            )
            turn(sim, spec, scorer.streams, scorer.add, scorer.watchers)
            scorer.close()
        finally:
            sim.close()

    def _crash_maps(
        self,
        sim: Simulation,
        base: FusionConfig,
        log: DriveLog,
        fused: list[tuple[LidarFrame, Scan]],
    ) -> MapSet:
        """LiDAR-only and obstacle maps of the scans the LiDAR-only robot saw (true poses)."""
        slab = (base.min_obstacle_height, base.max_obstacle_height)
        maps = _map_set(sim.world, self.settings, slab)
        for record in log.frames:
            frame = record.lidar
            maps.grid('lidar').integrate(
                frame.scan, frame.origin[0], frame.origin[1], frame.lidar_yaw
            )
        for frame, scan in fused:
            maps.grid('obstacle').integrate(scan, frame.origin[0], frame.origin[1], frame.lidar_yaw)
        return maps

    def result(self, files: list[str]) -> EvaluationResult:
        methods: dict[str, MethodResult] = {}
        for name in self.settings.methods:
            outcomes = [o for o in self.outcomes if o.method == name]
            maps = {
                label: compare_maps(map_set.grids[name], map_set.truth)
                for label, map_set in self.maps.items()
                if name in map_set.grids
            }
            methods[name] = MethodResult(
                method=name,
                description=method_spec(name).description,
                scan=self.tallies[name].summary(),
                scan_by_world={
                    world: tallies[name].summary() for world, tallies in self.world_tallies.items()
                },
                maps=maps,
                closed_loop=ClosedLoopSummary.of(outcomes) if outcomes else None,
                stream=dict(self.stream_counts.get(name, {})),
                drop_free_slots=self.drop_tallies[name].slots,
                false_drop_slots=self.drop_tallies[name].false_drops,
                scan_memory=self._memory_scan(name),
                closed_loop_memory=(
                    ClosedLoopSummary.of(memory) if (memory := _memory_outcomes(outcomes)) else None
                ),
            )
        settings = {
            key: list(value) if isinstance(value, tuple) else value
            for key, value in asdict(self.settings).items()
        }
        robots = {}
        for name in self.settings.amr_methods:
            outcomes = [o for o in self.amr_outcomes if o.method == name]
            robots[f'amr/{name}'] = RobotResult(
                robot='amr',
                method=name,
                description=AMR_DESCRIPTIONS[name],
                scan=self.amr_tallies[name].summary(),
                closed_loop=ClosedLoopSummary.of(outcomes) if outcomes else None,
                trials=outcomes,
            )
        terrain = (
            {
                name: self._terrain_result(name)
                for name in self.settings.methods
                if self.terrain.scans[name].slots or name in self.settings.terrain_methods
            }
            if self.terrain_specs
            else {}
        )
        return EvaluationResult(
            settings,
            methods,
            list(self.outcomes),
            files,
            robots=robots,
            terrain=terrain,
            terrain_trials=list(self.terrain.outcomes),
            retried=self.retried,
        )

    def _terrain_result(self, name: str) -> TerrainResult:
        outcomes = [o for o in self.terrain.outcomes if o.method == name]
        return TerrainResult(
            method=name,
            scan=self.terrain.scans[name].summary(),
            scan_slopes=self.terrain.slopes[name].summary(),
            drop_free_slots=self.terrain.drops[name].slots,
            false_drop_slots=self.terrain.drops[name].false_drops,
            slope_drop_free_slots=self.terrain.slope_drops[name].slots,
            slope_false_drop_slots=self.terrain.slope_drops[name].false_drops,
            closed_loop=ClosedLoopSummary.of(outcomes) if outcomes else None,
            slope_false_sources=dict(
                zip(SOURCES, self.terrain.slope_sources.get(name, ()), strict=False)
            ),
        )

    def _memory_scan(self, name: str) -> ScanMetrics | None:
        """Scan metrics over the memory trials' scans (None: no memory trial was run)."""
        groups = [g for g in self.world_tallies if g in MEMORY_FAMILIES]
        if not groups:
            return None
        tally = ScanTally()
        for group in groups:
            tally.merge(self.world_tallies[group][name])
        return tally.summary()


AMR_DESCRIPTIONS = {
    'lidar': 'both LiDARs merged into one 360-degree scan, no camera',
    'obstacle': 'both LiDARs, front and rear cameras (obstacle method, memory on)',
}


def _scores(method: str, methods: Sequence[str]) -> bool:
    """Whether `method`'s run of a trial scores every method on it (their streams see the
    same drive): `obstacle`'s, or the first method's when `obstacle` is not evaluated."""
    return method == 'obstacle' or ('obstacle' not in methods and method == methods[0])


def amr_specs(families: tuple[str, ...], variants: int) -> list[TrialSpec]:
    """`variants` seeded trials of each AMR family, family by family."""
    specs = []
    for name in families:
        for seed in range(variants):
            trial = amr_trial(name, seed)
            specs.append(
                TrialSpec(
                    name,
                    seed,
                    trial.goal,
                    AMR_TIME_LIMIT,
                    trial.waypoints,
                    reverse_waypoints=trial.reverse,
                )
            )
    return specs


class _AmrScorer:
    """The AMR's methods on the same scans: recall in view of either camera, all-around.

    Scored on the output grid (360 degrees, in the front LiDAR's frame), against the truth
    at each scan's stamp from the front LiDAR's true pose.
    """

    def __init__(self, evaluation: Evaluation, sim: Simulation, base: FusionConfig) -> None:
        from scanfuse.feeds import mounting_transform  # noqa: PLC0415
        from scanfuse.transforms import BODY_TO_OPTICAL  # noqa: PLC0415

        self.tallies = evaluation.amr_tallies
        self._names = set(evaluation.settings.amr_methods)
        self._pending: dict[int, dict[str, Scan]] = {}
        front = Extrinsics.from_config(base)
        more = [
            (
                camera,
                Extrinsics(
                    base_to_laser=front.base_to_laser,
                    base_to_camera_optical=mounting_transform(source) @ BODY_TO_OPTICAL,
                ),
            )
            for camera, source in zip(sim.cameras[1:], base.sources.cameras[1:], strict=True)
        ]
        self._sim, self._base, self._front, self._more = sim, base, front, more
        self.truths: SlotTruthBuilder | None = None  # on the output grid, from the first scan

    def _truths_for(self, scan: Scan) -> SlotTruthBuilder:
        sim, base = self._sim, self._base
        return SlotTruthBuilder(
            sim.world.obstacles,
            scan.grid,
            min_obstacle_height=base.min_obstacle_height,
            max_obstacle_height=base.max_obstacle_height,
            range_max=sim.lidar_profile.range_max,
            camera=sim.camera,
            extrinsics=self._front,
            footprint_radius=sim.robot.body_radius,
            more_cameras=self._more,
        )

    def add(self, name: str, frame: LidarFrame, scan: Scan) -> None:
        scans = self._pending.setdefault(frame.stamp_ns, {})
        scans[name] = scan
        if len(scans) == len(self._names):
            del self._pending[frame.stamp_ns]
            if self.truths is None:
                self.truths = self._truths_for(scan)
            truth = self.truths.build(frame)
            for method, fused in scans.items():
                self.tallies[method].add(fused.ranges, truth)


def _memory_outcomes(outcomes: list[TrialOutcome]) -> list[TrialOutcome]:
    return [o for o in outcomes if o.trial.rsplit('-', 1)[0] in MEMORY_FAMILIES]


class _Scorer:
    """Every scored method's stream in one run; scores each scan once all have released it.

    A scan's truth is the exact truth at its stamp (`LidarFrame.truth`'s instant): every
    method is scored on the same scans against the same truth.
    """

    def __init__(
        self,
        evaluation: Evaluation,
        label: str,
        group: str,
        sim: Simulation,
        base: FusionConfig,
        transforms: list[StampedTransform],
        *,
        mapped: bool,
        terrain: bool = False,
    ) -> None:
        """`terrain`: a terrain trial's scans, tallied apart (`Evaluation.terrain`): those on
        or near a ramp as well on their own; the truth's camera is the simulated one, and no
        `SeenSurfaces` (it places images on a level floor)."""
        settings = evaluation.settings
        self.evaluation = evaluation
        self.label = label
        self.terrain = terrain
        self.world = sim.world
        camera = sim.camera
        scored = (
            [name for name in settings.methods if name in settings.terrain_scored]
            if terrain
            else settings.methods
        )
        self.streams = [MethodStream(name, base, camera, transforms) for name in scored]
        for stream in self.streams:
            stream.record_sources = terrain
        self._names = {stream: stream.name for stream in self.streams}
        # On a world without drop-offs, each method that reports drops runs a twin with
        # detect_drops off on the same events: its scans tell the false drop slots.
        self._twins: dict[str, str] = {}
        if not sim.world.drops:
            for stream in list(self.streams):
                if reports_drops(stream.config, fuses=stream.spec.fuses):
                    twin = MethodStream(
                        stream.name, base.with_changes(detect_drops=False), camera, transforms
                    )
                    self._twins[stream.name] = f'{stream.name} {DROPS_OFF}'
                    self._names[twin] = self._twins[stream.name]
        self._scored = list(self.streams)  # without the twins
        extrinsics = Extrinsics.from_config(base)
        slab = (base.min_obstacle_height, base.max_obstacle_height)
        seen = (
            None
            if terrain
            else SeenSurfaces(
                sim.world.obstacles,
                sim.world.bounds,
                slab=slab,
                range_min=base.range_min,
                range_max=base.range_max,
                drops=sim.world.drops,
            )
        )
        self.streams = list(self._names)
        # Fed first, so that a frame counts as shown before any scan it releases is scored.
        self.watchers: list[Watcher] = [] if seen is None else [SeenObserver(seen, extrinsics)]
        if terrain:
            from scanfuse.sim.simulation import fusion_config  # noqa: PLC0415

            extrinsics = Extrinsics.from_config(fusion_config(sim.config, base))
        self._pending: dict[int, dict[str, Scan]] = {}
        self.truths = SlotTruthBuilder(
            sim.world.obstacles,
            sim.lidar_profile.grid,
            min_obstacle_height=base.min_obstacle_height,
            max_obstacle_height=base.max_obstacle_height,
            range_max=sim.lidar_profile.range_max,
            camera=camera,
            extrinsics=extrinsics,
            drops=sim.world.drops,
            footprint_radius=sim.robot.body_radius,
            seen=seen,
        )
        self.group_tallies = evaluation.world_tallies.setdefault(
            group, {name: ScanTally() for name in settings.methods}
        )
        self.maps = (
            evaluation.maps.setdefault(
                label,
                _map_set(sim.world, settings, (base.min_obstacle_height, base.max_obstacle_height)),
            )
            if mapped and label in evaluation.mapped_labels
            else None
        )
        self.front = _obstacle_front(sim.world)
        self.costmaps = None
        if label == COSTMAP_TRIAL:
            spec = GridSpec.covering(sim.world.bounds, 0.05, margin=0.3)
            self.costmaps = evaluation.costmaps.setdefault(
                label,
                CostmapSet(
                    sim.world,
                    {name: Costmap(spec) for name in COSTMAP_METHODS if name in settings.methods},
                ),
            )

    def add(self, stream: MethodStream, frame: LidarFrame, scan: Scan) -> None:
        name = self._names.get(stream)
        if name is None:
            return
        scans = self._pending.setdefault(frame.stamp_ns, {})
        scans[name] = scan
        if len(scans) == len(self._names):
            del self._pending[frame.stamp_ns]
            self._score(frame, scans)

    def _score(self, frame: LidarFrame, scans: dict[str, Scan]) -> None:
        evaluation = self.evaluation
        truth = self.truths.build(frame)
        twins = {self._twins[name]: scans.pop(self._twins[name]) for name in self._twins}
        terrain = evaluation.terrain
        slope = self.terrain and self.world.on_slope(*frame.origin[:2], SLOPE_REACH)
        sources = {
            name: stream.sources.pop(frame.stamp_ns, None)
            for stream, name in self._names.items()
            if stream.record_sources
        }
        for name, scan in scans.items():
            made_by = sources.get(name)
            if slope and made_by is not None:
                false = false_obstacle_slots(scan.ranges, truth.truth)
                terrain.add_slope_sources(name, count_sources(made_by, false))
            tallies = [self.group_tallies[name]]
            drops = []
            if self.terrain:
                tallies.append(terrain.scans[name])
                drops.append(terrain.drops[name])
                if slope:
                    tallies.append(terrain.slopes[name])
                    drops.append(terrain.slope_drops[name])
            else:
                tallies.append(evaluation.tallies[name])
                drops.append(evaluation.drop_tallies[name])
            for tally in tallies:
                tally.add(scan.ranges, truth)
            twin = twins.get(self._twins.get(name, ''))
            if twin is not None:
                mask = false_drop_slots(scan.ranges, twin.ranges, truth.truth)
                for drop_tally in drops:
                    drop_tally.add(mask)
            if self.maps is not None:
                self.maps.grid(name).integrate(scan, *frame.origin[:2], frame.lidar_yaw)
            if self.costmaps is not None and name in self.costmaps.costmaps:
                self.costmaps.costmaps[name].update(scan, *frame.origin[:2], frame.lidar_yaw)
        if self.costmaps is not None:
            self.costmaps.robot = (frame.pose.x, frame.pose.y, frame.pose.yaw)
        front = self.front
        wanted = front is not None and self.label not in evaluation.snapshots
        if front is not None and wanted and front - frame.pose.x <= FIGURE_DISTANCE:
            evaluation.snapshots[self.label] = Snapshot(self.label, frame, scans)

    def close(self) -> None:
        """Add up what the streams did (every stream released every scan: none is lost); the
        terrain trials' streams are not counted (only some methods score them)."""
        if self.terrain:
            return
        for stream in self._scored:
            counts = stream.counts
            if counts is None:
                continue
            total = self.evaluation.stream_counts.setdefault(stream.name, {})
            for key, value in (
                ('scans', counts.scans),
                ('fused', counts.fused),
                ('compensated', counts.compensated),
                ('deskewed', counts.deskewed),
                ('passed', counts.passed_through),
            ):
                total[key] = total.get(key, 0) + value


class SeenObserver:
    """A watcher (`closed_loop.Watcher`): marks what each depth image shows
    (`SeenSurfaces`), placed at the simulator's true pose at the image's stamp."""

    def __init__(self, seen: SeenSurfaces, extrinsics: Extrinsics) -> None:
        self.seen = seen
        self.base_to_optical = extrinsics.base_to_camera_optical
        self.true_poses = OdometryHistory()

    def add_state(self, sample: StateSample) -> None:
        pose = sample.true_pose
        self.true_poses.add(sample.stamp_ns, PlanarPose(pose.x, pose.y, pose.yaw))

    def add_depth(self, frame: DepthFrame) -> None:
        pose = self.true_poses.pose_at(frame.stamp_ns).pose
        if pose is not None:
            base = Transform.from_rpy(0.0, 0.0, pose.yaw, (pose.x, pose.y, 0.0))
            self.seen.add(frame.depth, frame.camera, base @ self.base_to_optical)


def _obstacle_front(world: World) -> float | None:
    """x of the nearest face of the bookshelf or barricade, or of the ledge's edge, for the
    scan figure's frame."""
    if world.name == 'ledge':
        return float(min(drop.rectangle[0] for drop in world.drops))
    kinds = {'bookshelf': 'shelf_board', 'barricade': 'barricade_base'}
    kind = kinds.get(world.name)
    if kind is None:
        return None
    return float(min(o.footprint[:, 0].min() for o in world.obstacles if o.kind == kind))


# ---------------------------------------------------------------- writing


def odometry_world_poses(world: World, log: DriveLog) -> list[tuple[float, float, float]]:
    """Where the wheel odometry believed the LiDAR was, in the world frame, per kept frame."""
    poses = []
    for record in log.frames:
        believed = odom_to_world(world.start, record.odometry)
        poses.append((believed.x, believed.y, believed.yaw))
    return poses


__all__ = ['Evaluation', 'EvaluationSettings', 'Progress']
