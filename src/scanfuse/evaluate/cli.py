"""The `scanfuse evaluate` command's work: settings from options, rich progress, the table."""

from __future__ import annotations

import os
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from scanfuse.cluster import RayCluster, backend_of
from scanfuse.config import NODE_ONLY, FusionConfig, read_ros_params
from scanfuse.errors import ConfigError
from scanfuse.progress import RichProgress
from scanfuse.sim.worlds import TERRAIN_WORLDS, WORLDS

# The simulator's worlds but the terrain ones, `memory`: the memory trials
# (evaluate/memory_trials.py), and `terrain`: the terrain trials (evaluate/terrain_trials.py,
# on the terrain worlds).
EVALUATION_WORLDS = (
    *(name for name in WORLDS if name not in TERRAIN_WORLDS),
    'memory',
    'terrain',
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from rich.console import Console

    from scanfuse.cluster import Backend
    from scanfuse.evaluate.results import EvaluationResult
    from scanfuse.evaluate.runner import EvaluationSettings
    from scanfuse.evaluate.sweep import SweepResult


def parse_worlds(worlds: str | None) -> tuple[str, ...] | None:
    if worlds is None:
        return None
    names = tuple(name.strip() for name in worlds.split(',') if name.strip())
    unknown = [name for name in names if name not in EVALUATION_WORLDS]
    if unknown or not names:
        given = ', '.join(unknown) or '(none given)'
        msg = f'unknown world(s) {given}; choose from {", ".join(EVALUATION_WORLDS)}'
        raise ConfigError(msg)
    return names


def parameters_of(path: Path) -> dict[str, Any]:
    """A parameter file's fusion parameters (the node's own, such as pair_wait, left out)."""
    values = {k: v for k, v in read_ros_params(path).items() if k not in NODE_ONLY}
    FusionConfig.from_dict(values)  # wrong values fail here, naming the parameter
    return values


def check_output_folder(out: Path) -> None:
    """Refuse (ConfigError) an --out that cannot become a folder to write in, before any
    work: an existing file, or a path under a file or a folder that cannot be written."""
    if out.exists() and not out.is_dir():
        msg = f'--out {out} exists and is not a folder; give a folder path'
        raise ConfigError(msg)
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        msg = f'--out {out}: {existing} is not a folder; give a folder path'
        raise ConfigError(msg)
    if not os.access(existing, os.W_OK | os.X_OK):
        msg = f'--out {out}: cannot write in {existing}; give a folder you can write'
        raise ConfigError(msg)


def with_scored(settings: EvaluationSettings, names: Sequence[str]) -> EvaluationSettings:
    """`settings` with the methods `names` scored too, on every trial's and every terrain
    trial's scans (`--score`); a wrong name or parameter fails here, before any trial."""
    from scanfuse.evaluate.methods import method_spec  # noqa: PLC0415

    for name in names:
        method_spec(name)
    extra = [name for name in dict.fromkeys(names) if name not in settings.methods]
    terrain = [name for name in dict.fromkeys(names) if name not in settings.terrain_scored]
    return replace(
        settings,
        methods=(*settings.methods, *extra),
        terrain_scored=(*settings.terrain_scored, *terrain),
    )


def settings_of(
    *,
    quick: bool,
    worlds: str | None = None,
    trials: int | None = None,
    terrain_trials: int | None = None,
    params: Path | None = None,
    scored: Sequence[str] = (),
) -> EvaluationSettings:
    """The evaluation `scanfuse evaluate`'s options ask for (ConfigError on a wrong one)."""
    from scanfuse.evaluate.runner import EvaluationSettings  # noqa: PLC0415

    changes: dict[str, object] = {}
    if params is not None:
        changes['params'] = parameters_of(params)
    names = parse_worlds(worlds)
    if names is not None:
        changes['worlds'] = names
    for option, value, least in (('--trials', trials, 0), ('--terrain-trials', terrain_trials, 1)):
        if value is not None and value < least:
            msg = f'{option} must be {least} or more, got {value}'
            raise ConfigError(msg)
    if trials is not None:
        changes['trials'] = trials
    if terrain_trials is not None:
        changes['terrain_trials'] = terrain_trials
    make = EvaluationSettings.quick if quick else EvaluationSettings
    return with_scored(make(**changes), scored)  # type: ignore[arg-type]


def run_evaluate(
    out: Path,
    *,
    quick: bool,
    worlds: str | None,
    trials: int | None,
    console: Console,
    terrain_trials: int | None = None,
    jobs: int = 1,
    params: Path | None = None,
    cluster: str | None = None,
    max_retries: int | None = None,
    sweeps: Sequence[str] = (),
    scored: Sequence[str] = (),
) -> EvaluationResult | SweepResult:
    """Run the evaluation into `out` and print the headline table and where things are;
    `scored`: methods scored besides the default ones, on the same scans (they do not
    drive), such as `obstacle[memory_scan_matching=false]`."""
    from scanfuse.sim.headless_gl import choose_headless_gl  # noqa: PLC0415

    # Depth through mujoco.Renderer where a headless GL works (before MuJoCo's import).
    choose_headless_gl()
    from scanfuse.evaluate.report import amr_table, table, terrain_table  # noqa: PLC0415
    from scanfuse.evaluate.write import run_evaluation  # noqa: PLC0415

    check_output_folder(out)
    backend = backend_of(jobs, cluster, max_retries)
    settings = settings_of(
        quick=quick,
        worlds=worlds,
        trials=trials,
        terrain_trials=terrain_trials,
        params=params,
        scored=scored,
    )
    if sweeps:
        return _run_sweep(out, settings, sweeps, backend, console)
    result = run_evaluation(out, settings, RichProgress(console), backend=backend)
    console.print(table(result))
    robot_rows = amr_table(result)
    if robot_rows is not None:
        console.print(robot_rows)
    terrain_rows = terrain_table(result)
    if terrain_rows is not None:
        console.print(terrain_rows)
    if isinstance(backend, RayCluster):
        console.print(
            f'{backend.describe()}: {result.retried} trial(s) retried after a worker died'
        )
    console.print(f'report: {out / "report.md"}')
    console.print(f'results: {out / "results.json"}')
    return result


def _run_sweep(
    out: Path,
    settings: EvaluationSettings,
    sweeps: Sequence[str],
    backend: Backend,
    console: Console,
) -> SweepResult:
    """Every combination of the sweeps on `settings`' trials; the table and where it is."""
    from rich.table import Table  # noqa: PLC0415

    from scanfuse.evaluate import sweep  # noqa: PLC0415

    axes = sweep.parse_sweeps(sweeps)
    result = sweep.run_sweep(settings, axes, backend, RichProgress(console))
    sweep.write_sweep(result, out)
    table = Table('setting', 'method', 'recall', 'false obstacles', 'collisions', 'goals', 'trials')
    for row in result.rows():
        table.add_row(
            sweep.setting_label(row.setting),
            row.method,
            f'{100 * row.recall:.1f} %',
            f'{100 * row.false_obstacle_rate:.1f} %',
            f'{row.collisions:g}',
            f'{row.reached:g}',
            str(row.trials),
        )
    console.print(table)
    if isinstance(backend, RayCluster):
        console.print(
            f'{backend.describe()}: {result.retried} trial(s) retried after a worker died'
        )
    console.print(f'comparison: {out / "sweep.md"}, {out / "sweep.json"}, {out / "sweep.png"}')
    return result
