"""Typed evaluation results that are saved as JSON, loaded back and compared between runs."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

from scanfuse.errors import ScanfuseError
from scanfuse.evaluate.closed_loop import TrialOutcome
from scanfuse.evaluate.mapping import MapAgreement
from scanfuse.evaluate.metrics import ScanMetrics

if TYPE_CHECKING:
    from pathlib import Path

RESULTS_VERSION = 1


class ResultsError(ScanfuseError):
    """A results file cannot be read."""


@dataclass(frozen=True)
class ClosedLoopSummary:
    """Closed-loop trials of one method."""

    trials: int
    collisions: int
    reached: int
    mean_path_length: float  # metres, trials that reached the goal
    mean_time: float  # simulated seconds, trials that reached the goal
    falls: int = 0  # trials in which the base left the floor plane (drop-off worlds)
    reversing_collisions: int = 0  # trials whose first contact came while driving backwards

    @classmethod
    def of(cls, outcomes: list[TrialOutcome]) -> ClosedLoopSummary:
        arrived = [o for o in outcomes if o.reached and not o.collided and not o.fell]
        return cls(
            trials=len(outcomes),
            collisions=sum(o.collided for o in outcomes),
            reached=sum(o.reached for o in outcomes),
            mean_path_length=_mean([o.path_length for o in arrived]),
            mean_time=_mean([o.duration for o in arrived]),
            falls=sum(o.fell for o in outcomes),
            reversing_collisions=sum(o.collided and o.reversing_contact for o in outcomes),
        )


def _mean(values: list[float]) -> float:
    return sum(values) / len(values) if values else float('nan')


@dataclass(frozen=True)
class MethodResult:
    """Everything measured for one method."""

    method: str
    description: str
    scan: ScanMetrics
    scan_by_world: dict[str, ScanMetrics]
    maps: dict[str, MapAgreement]
    closed_loop: ClosedLoopSummary | None
    # What the method's streams did with the scored scans: scans, fused, compensated,
    # deskewed, passed (empty for `lidar`, which has no stream).
    stream: dict[str, int] = field(default_factory=dict)
    # Slots scored on worlds without drop-offs, and the false drop slots among them
    # (`scanfuse.evaluate.drops`).
    drop_free_slots: int = 0
    false_drop_slots: int = 0

    @property
    def false_drop_rate(self) -> float:
        return self.false_drop_slots / self.drop_free_slots if self.drop_free_slots else math.nan

    # The memory trials alone (evaluate/memory_trials.py): their scans and closed loop.
    scan_memory: ScanMetrics | None = None
    closed_loop_memory: ClosedLoopSummary | None = None


@dataclass(frozen=True)
class RobotResult:
    """One method on another robot (the two-LiDAR, two-camera `amr`): its scans and trials.

    `scan.recall` counts the low-obstacle slots in view of either camera, `scan.recall_near`
    those within 1 m of the footprint in any direction; `closed_loop.reversing_collisions`
    the trials whose first contact came while the robot was backing out.
    """

    robot: str
    method: str
    description: str
    scan: ScanMetrics
    closed_loop: ClosedLoopSummary | None
    trials: list[TrialOutcome] = field(default_factory=list)


@dataclass(frozen=True)
class TerrainResult:
    """One method on the terrain trials (`terrain_trials`): its scans over every terrain trial
    and over those on or near a ramp (`scan_slopes`), its false drop slots likewise (on the
    terrain worlds without drop-offs), and the trials it drove (None: it drove none)."""

    method: str
    scan: ScanMetrics
    scan_slopes: ScanMetrics
    drop_free_slots: int
    false_drop_slots: int
    slope_drop_free_slots: int
    slope_false_drop_slots: int
    closed_loop: ClosedLoopSummary | None
    # A fusing method's false obstacle slots on slopes by the source that made them
    # (`attribution.SOURCES`: LiDAR, camera, memory); empty for the others.
    slope_false_sources: dict[str, int] = field(default_factory=dict)

    @property
    def false_drop_rate(self) -> float:
        return self.false_drop_slots / self.drop_free_slots if self.drop_free_slots else math.nan

    @property
    def slope_false_drop_rate(self) -> float:
        slots = self.slope_drop_free_slots
        return self.slope_false_drop_slots / slots if slots else math.nan


@dataclass(frozen=True)
class EvaluationResult:
    """One evaluation run: settings, per-method results, every trial, and the files written."""

    settings: dict[str, Any]
    methods: dict[str, MethodResult]
    trials: list[TrialOutcome]
    files: list[str] = field(default_factory=list)
    version: int = RESULTS_VERSION
    robots: dict[str, RobotResult] = field(default_factory=dict)  # keyed 'amr/<method>'
    terrain: dict[str, TerrainResult] = field(default_factory=dict)  # keyed by method
    terrain_trials: list[TrialOutcome] = field(default_factory=list)
    retried: int = 0  # trials run again on a Ray cluster after their worker died

    def headline(self) -> dict[str, dict[str, float]]:
        """The numbers the report leads with, per method."""
        table: dict[str, dict[str, float]] = {}
        for name, result in self.methods.items():
            row = {
                'recall': result.scan.recall,
                'false_obstacle_rate': result.scan.false_obstacle_rate,
                'median_error': result.scan.median_error,
                'recall_near': result.scan.recall_near,
            }
            if result.scan_memory is not None:
                row['memory_recall_near'] = result.scan_memory.recall_near
                row['memory_false_obstacle_rate'] = result.scan_memory.false_obstacle_rate
            if result.closed_loop_memory is not None:
                row['memory_trials'] = result.closed_loop_memory.trials
                row['memory_collisions'] = result.closed_loop_memory.collisions
            if result.closed_loop is not None:
                row['trials'] = result.closed_loop.trials
                row['collisions'] = result.closed_loop.collisions
                row['reached'] = result.closed_loop.reached
                row['falls'] = result.closed_loop.falls
            table[name] = row
        for key, robot in self.robots.items():
            row = {'recall': robot.scan.recall, 'recall_near': robot.scan.recall_near}
            if robot.closed_loop is not None:
                row['trials'] = robot.closed_loop.trials
                row['collisions'] = robot.closed_loop.collisions
                row['reversing_collisions'] = robot.closed_loop.reversing_collisions
                row['reached'] = robot.closed_loop.reached
            table[key] = row
        for name, terrain in self.terrain.items():
            row = {
                'recall': terrain.scan_slopes.recall,
                'false_obstacle_rate': terrain.scan_slopes.false_obstacle_rate,
                'false_drop_rate': terrain.slope_false_drop_rate,
            }
            if terrain.closed_loop is not None:
                row['trials'] = terrain.closed_loop.trials
                row['collisions'] = terrain.closed_loop.collisions
                row['falls'] = terrain.closed_loop.falls
                row['reached'] = terrain.closed_loop.reached
            table[f'terrain/{name}'] = row
        return table

    def compare(self, other: EvaluationResult) -> dict[str, dict[str, float]]:
        """Headline differences `self - other`, per method both runs have."""
        mine, theirs = self.headline(), other.headline()
        return {
            method: {
                key: value - theirs[method][key]
                for key, value in row.items()
                if key in theirs[method]
            }
            for method, row in mine.items()
            if method in theirs
        }

    def to_json(self) -> str:
        return json.dumps(_nan_to_none(asdict(self)), indent=2, sort_keys=False)

    def save(self, path: Path) -> Path:
        path.write_text(self.to_json(), encoding='utf-8')
        return path

    @classmethod
    def from_json(cls, text: str) -> EvaluationResult:
        try:
            data = json.loads(text)
            version = data['version']
            if version != RESULTS_VERSION:
                msg = f'results file version {version}, this scanfuse reads {RESULTS_VERSION}'
                raise ResultsError(msg)
            return cls(
                settings=data['settings'],
                methods={name: _method_from_dict(value) for name, value in data['methods'].items()},
                trials=[TrialOutcome(**_none_to_nan(trial)) for trial in data['trials']],
                files=list(data['files']),
                version=version,
                robots={
                    key: _robot_from_dict(value) for key, value in data.get('robots', {}).items()
                },
                terrain={
                    key: _terrain_from_dict(value) for key, value in data.get('terrain', {}).items()
                },
                terrain_trials=[
                    TrialOutcome(**_none_to_nan(trial)) for trial in data.get('terrain_trials', [])
                ],
                retried=int(data.get('retried', 0)),
            )
        except (KeyError, TypeError, json.JSONDecodeError) as err:
            msg = f'not a scanfuse results.json ({err}); write one with `scanfuse evaluate`'
            raise ResultsError(msg) from err

    @classmethod
    def load(cls, path: Path) -> EvaluationResult:
        return cls.from_json(path.read_text(encoding='utf-8'))


def _scan_from_dict(data: dict[str, Any]) -> ScanMetrics:
    return ScanMetrics(**_none_to_nan(data))


def _robot_from_dict(data: dict[str, Any]) -> RobotResult:
    loop = data['closed_loop']
    return RobotResult(
        robot=data['robot'],
        method=data['method'],
        description=data['description'],
        scan=_scan_from_dict(data['scan']),
        closed_loop=None if loop is None else ClosedLoopSummary(**_none_to_nan(loop)),
        trials=[TrialOutcome(**_none_to_nan(trial)) for trial in data.get('trials', [])],
    )


def _terrain_from_dict(data: dict[str, Any]) -> TerrainResult:
    loop = data['closed_loop']
    return TerrainResult(
        method=data['method'],
        scan=_scan_from_dict(data['scan']),
        scan_slopes=_scan_from_dict(data['scan_slopes']),
        drop_free_slots=int(data['drop_free_slots']),
        false_drop_slots=int(data['false_drop_slots']),
        slope_drop_free_slots=int(data['slope_drop_free_slots']),
        slope_false_drop_slots=int(data['slope_false_drop_slots']),
        closed_loop=None if loop is None else ClosedLoopSummary(**_none_to_nan(loop)),
        slope_false_sources={k: int(v) for k, v in data.get('slope_false_sources', {}).items()},
    )


def _method_from_dict(data: dict[str, Any]) -> MethodResult:
    loop = data['closed_loop']
    return MethodResult(
        method=data['method'],
        description=data['description'],
        scan=_scan_from_dict(data['scan']),
        scan_by_world={k: _scan_from_dict(v) for k, v in data['scan_by_world'].items()},
        maps={k: MapAgreement(**_none_to_nan(v)) for k, v in data['maps'].items()},
        closed_loop=None if loop is None else ClosedLoopSummary(**_none_to_nan(loop)),
        stream={str(k): int(v) for k, v in data.get('stream', {}).items()},
        drop_free_slots=int(data.get('drop_free_slots', 0)),
        false_drop_slots=int(data.get('false_drop_slots', 0)),
        scan_memory=(
            None if data.get('scan_memory') is None else _scan_from_dict(data['scan_memory'])
        ),
        closed_loop_memory=(
            None
            if data.get('closed_loop_memory') is None
            else ClosedLoopSummary(**_none_to_nan(data['closed_loop_memory']))
        ),
    )


def _nan_to_none(value: Any) -> Any:
    """JSON has no NaN: store it as null."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {key: _nan_to_none(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_nan_to_none(item) for item in value]
    return value


def _none_to_nan(value: Any) -> Any:
    if value is None:
        return float('nan')
    if isinstance(value, dict):
        return {key: _none_to_nan(item) for key, item in value.items()}
    return value
