"""`evaluate`: closed-loop trials, scan metrics, maps and figures for every method.

Steps: run every trial with every closed-loop method; on the frames of the
`obstacle` runs (the robot drives safely, so the frames cover the approach to
each obstacle) score every method's fused scan against the ground truth and
build each method's map; keep a few frames for the figures; write results.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import yaml

from scanfuse.evaluate.closed_loop import (
    CLOSED_LOOP_TIME_LIMIT,
    DriveLog,
    TrialOutcome,
    TrialSpec,
    drive,
    evaluation_world,
    odom_to_world,
    trial_specs,
)
from scanfuse.evaluate.groundtruth import SlotTruthBuilder
from scanfuse.evaluate.mapping import (
    GridSpec,
    OccupancyGrid,
    compare_maps,
    rasterize_footprints,
    save_map,
)
from scanfuse.evaluate.methods import CLOSED_LOOP_METHODS, METHODS, MethodRunner
from scanfuse.evaluate.metrics import ScanTally
from scanfuse.evaluate.results import ClosedLoopSummary, EvaluationResult, MethodResult
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

    from scanfuse.config import FusionConfig
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import LidarFrame, Simulation
    from scanfuse.sim.worlds import World

MAP_RESOLUTION = 0.05
FIGURE_DISTANCE = 1.0  # metres from the robot to the obstacle's front in the scan figures


@dataclass(frozen=True)
class EvaluationSettings:
    """What an evaluation runs; `quick()` is the small version for tests and the demo."""

    worlds: tuple[str, ...] = ('bookshelf', 'barricade', 'clutter')
    trials: int = 30  # seeded clutter worlds
    methods: tuple[str, ...] = tuple(METHODS)
    closed_loop_methods: tuple[str, ...] = CLOSED_LOOP_METHODS
    resolution: tuple[int, int] = (424, 240)
    time_limit: float = CLOSED_LOOP_TIME_LIMIT
    noise: bool = True
    map_resolution: float = MAP_RESOLUTION
    mapped_trials: int = 3  # first trials whose frames are mapped per method

    @classmethod
    def quick(cls, **changes: Any) -> EvaluationSettings:
        base = cls(
            trials=2,
            closed_loop_methods=('lidar', 'obstacle'),
            resolution=(256, 144),
            time_limit=20.0,
            mapped_trials=3,
        )
        return replace(base, **changes)


class Progress(Protocol):
    """Receives progress of the long work."""

    def start(self, description: str, total: int) -> None: ...
    def advance(self) -> None: ...
    def finish(self) -> None: ...


class NullProgress:
    """The do-nothing progress that keeps the loop free of `if progress`."""

    def start(self, description: str, total: int) -> None:
        del description, total

    def advance(self) -> None:
        pass

    def finish(self) -> None:
        pass


def base_config(sim: Simulation) -> FusionConfig:
    """The fusion configuration that matches the simulated robot's mounting and camera."""
    from scanfuse.sim.simulation import fusion_config  # noqa: PLC0415

    return fusion_config(sim.config)


def make_simulation(trial: TrialSpec, settings: EvaluationSettings) -> Simulation:
    """The trial's simulation; depth through mujoco.Renderer when a headless GL was chosen."""
    from scanfuse.sim.simulation import SimConfig, Simulation  # noqa: PLC0415

    config = SimConfig(
        world=trial.world,
        seed=trial.seed,
        resolution=settings.resolution,
        depth_rate=10.0,
        noise=settings.noise,
    )
    return Simulation(config, evaluation_world(trial.world, trial.seed))


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


class Evaluation:
    """One evaluation run; `run()` does the work, `result()` packs it up."""

    def __init__(self, settings: EvaluationSettings, progress: Progress | None = None) -> None:
        for name in (*settings.methods, *settings.closed_loop_methods):
            if name not in METHODS:
                from scanfuse.errors import ConfigError  # noqa: PLC0415

                msg = f'unknown method {name!r}; choose from {", ".join(METHODS)}'
                raise ConfigError(msg)
        self.settings = settings
        self.progress: Progress = progress or NullProgress()
        self.trials = trial_specs(list(settings.worlds), settings.trials, settings.time_limit)
        self.tallies = {name: ScanTally() for name in settings.methods}
        self.world_tallies: dict[str, dict[str, ScanTally]] = {}
        self.outcomes: list[TrialOutcome] = []
        self.maps: dict[str, MapSet] = {}
        self.snapshots: dict[str, Snapshot] = {}
        self.collision_logs: dict[str, tuple[World, DriveLog, TrialOutcome, float]] = {}
        # Maps of the LiDAR-only robot's run, from its own scans and from the fused ones.
        self.crash_maps: dict[str, MapSet] = {}

    def run(self) -> None:
        jobs = [(t, m) for t in self.trials for m in self.settings.closed_loop_methods]
        self.progress.start('closed-loop trials', len(jobs))
        for trial, method in jobs:
            self._trial(trial, method)
            self.progress.advance()
        self.progress.finish()

    def _trial(self, trial: TrialSpec, method: str) -> None:
        sim = make_simulation(trial, self.settings)
        try:
            base = base_config(sim)
            runner = MethodRunner(METHODS[method], base, sim.camera)
            scoring = method == 'obstacle' or (
                'obstacle' not in self.settings.closed_loop_methods
                and method == self.settings.closed_loop_methods[0]
            )
            on_frame = self._scorer(trial, sim, base) if scoring else None
            keep = method == 'lidar' and trial.world in {'bookshelf', 'barricade'}

            def scan_of(scan: Scan, depth: npt.NDArray[np.uint16]) -> Scan:
                return runner.scan(scan, depth, sim.camera)

            outcome, log = drive(
                sim, trial, scan_of, method=method, keep_frames=keep, on_frame=on_frame
            )
            self.outcomes.append(outcome)
            if keep:
                self.collision_logs[trial.label] = (sim.world, log, outcome, sim.robot.body_radius)
                self.crash_maps[trial.label] = self._crash_maps(sim, base, log)
        finally:
            sim.close()

    def _crash_maps(self, sim: Simulation, base: FusionConfig, log: DriveLog) -> MapSet:
        """LiDAR-only and obstacle maps of the frames the LiDAR-only robot saw (true poses)."""
        slab = (base.min_obstacle_height, base.max_obstacle_height)
        maps = _map_set(sim.world, self.settings, slab)
        fused = MethodRunner(METHODS['obstacle'], base, sim.camera)
        for record in log.frames:
            frame = record.lidar
            pose = (frame.origin[0], frame.origin[1], frame.pose.yaw)
            maps.grid('lidar').integrate(frame.scan, *pose)
            scan = fused.scan(frame.scan, record.depth, sim.camera)
            maps.grid('obstacle').integrate(scan, *pose)
        return maps

    def _scorer(
        self, trial: TrialSpec, sim: Simulation, base: FusionConfig
    ) -> Callable[[LidarFrame, npt.NDArray[np.uint16]], None]:
        camera = sim.camera
        runners = {
            name: MethodRunner(METHODS[name], base, camera) for name in self.settings.methods
        }
        truths = SlotTruthBuilder(
            sim.world.obstacles,
            sim.lidar_profile.grid,
            min_obstacle_height=base.min_obstacle_height,
            max_obstacle_height=base.max_obstacle_height,
            range_max=sim.lidar_profile.range_max,
            camera=camera,
            extrinsics=Extrinsics.from_config(base),
        )
        world_tallies = self.world_tallies.setdefault(
            trial.world, {name: ScanTally() for name in self.settings.methods}
        )
        mapped = len(self.maps) < self.settings.mapped_trials
        maps = (
            self.maps.setdefault(
                trial.label,
                _map_set(
                    sim.world, self.settings, (base.min_obstacle_height, base.max_obstacle_height)
                ),
            )
            if mapped
            else None
        )
        front = _obstacle_front(sim.world)

        def on_frame(frame: LidarFrame, depth: npt.NDArray[np.uint16]) -> None:
            truth = truths.build(frame)
            scans = {
                name: runner.scan(frame.scan, depth, camera) for name, runner in runners.items()
            }
            for name, scan in scans.items():
                self.tallies[name].add(scan.ranges, truth)
                world_tallies[name].add(scan.ranges, truth)
                if maps is not None:
                    maps.grid(name).integrate(scan, *frame.origin[:2], frame.pose.yaw)
            wanted = front is not None and trial.label not in self.snapshots
            if front is not None and wanted and front - frame.pose.x <= FIGURE_DISTANCE:
                self.snapshots[trial.label] = Snapshot(trial.label, frame, scans)

        return on_frame

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
                description=METHODS[name].description,
                scan=self.tallies[name].summary(),
                scan_by_world={
                    world: tallies[name].summary() for world, tallies in self.world_tallies.items()
                },
                maps=maps,
                closed_loop=ClosedLoopSummary.of(outcomes) if outcomes else None,
            )
        settings = {
            key: list(value) if isinstance(value, tuple) else value
            for key, value in asdict(self.settings).items()
        }
        return EvaluationResult(settings, methods, list(self.outcomes), files)


def _obstacle_front(world: World) -> float | None:
    """x of the nearest face of the bookshelf or barricade, for the scan figure's frame."""
    kinds = {'bookshelf': 'shelf_board', 'barricade': 'barricade_base'}
    kind = kinds.get(world.name)
    if kind is None:
        return None
    return float(min(o.footprint[:, 0].min() for o in world.obstacles if o.kind == kind))


# ---------------------------------------------------------------- writing


def write_outputs(evaluation: Evaluation, out: Path, config: FusionConfig) -> EvaluationResult:
    """Figures, maps, the configuration, results.json and report.md in `out`."""
    from scanfuse.evaluate import report  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    files = report.write_figures(evaluation, out)
    files += _write_maps(evaluation, out)
    config_path = out / 'scanfuse.yaml'
    config_path.write_text(
        yaml.safe_dump(config.to_ros_params(), sort_keys=False), encoding='utf-8'
    )
    settings_path = out / 'evaluation.yaml'
    settings_path.write_text(
        yaml.safe_dump(
            {
                k: list(v) if isinstance(v, tuple) else v
                for k, v in asdict(evaluation.settings).items()
            },
            sort_keys=False,
        ),
        encoding='utf-8',
    )
    files += [config_path.name, settings_path.name, 'results.json', 'report.md']
    result = evaluation.result(sorted(files))
    result.save(out / 'results.json')
    (out / 'report.md').write_text(report.markdown(result), encoding='utf-8')
    return result


def _write_maps(evaluation: Evaluation, out: Path) -> list[str]:
    maps_dir = out / 'maps'
    if maps_dir.exists():
        shutil.rmtree(maps_dir)
    maps_dir.mkdir()
    written = []
    for label, map_set in evaluation.maps.items():
        for name in ('lidar', 'obstacle'):
            if name in map_set.grids:
                pgm, description = save_map(map_set.grids[name], maps_dir / f'{label}_{name}')
                written += [f'maps/{pgm.name}', f'maps/{description.name}']
    return written


def odometry_world_poses(world: World, log: DriveLog) -> list[tuple[float, float, float]]:
    """Where the wheel odometry believed the LiDAR was, in the world frame, per kept frame."""
    poses = []
    for record in log.frames:
        believed = odom_to_world(world.start, record.odometry)
        poses.append((believed.x, believed.y, believed.yaw))
    return poses


def run_evaluation(
    out: Path, settings: EvaluationSettings, progress: Progress | None = None
) -> EvaluationResult:
    """Run the evaluation and write everything into `out`."""
    evaluation = Evaluation(settings, progress)
    evaluation.run()
    reference = make_simulation(evaluation.trials[0], settings)
    try:
        config = base_config(reference)
    finally:
        reference.close()
    return write_outputs(evaluation, out, config)


__all__ = ['Evaluation', 'EvaluationSettings', 'Progress', 'run_evaluation']
