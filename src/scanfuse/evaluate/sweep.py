"""`scanfuse evaluate --sweep NAME=V1,V2 ...`: every combination of parameter values on the
same seeded trials, one comparison table (markdown and JSON) and one figure.

Each combination is the evaluation's settings with those fusion parameters (the `--params`
file's values, changed); the jobs of every combination go to one backend together (a local
pool or a Ray cluster), and each combination's parts are merged in its serial order, so a
row is what a separate run with that setting gives.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any

import yaml

from scanfuse.cluster import LocalPool, run_tasks
from scanfuse.errors import ConfigError
from scanfuse.evaluate.runner import Evaluation, _run_job
from scanfuse.progress import NullProgress

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from scanfuse.cluster import Backend
    from scanfuse.evaluate.results import EvaluationResult
    from scanfuse.evaluate.runner import EvaluationSettings
    from scanfuse.progress import Progress

METRICS = (
    ('recall', 'recall'),
    ('false_obstacle_rate', 'false obstacles'),
    ('collisions', 'collisions'),
    ('reached', 'goals reached'),
)


@dataclass(frozen=True)
class SweepAxis:
    """One swept parameter and its values, in the order given."""

    name: str
    values: tuple[Any, ...]


def parse_sweeps(texts: Sequence[str]) -> list[SweepAxis]:
    """`name=v1,v2` options (values read as YAML scalars: 0.05, 10, true, obstacle)."""
    axes: list[SweepAxis] = []
    for text in texts:
        name, equals, values = text.partition('=')
        name = name.strip()
        parsed = tuple(yaml.safe_load(value) for value in values.split(',') if value.strip())
        if not equals or not name or not parsed:
            msg = f'--sweep {text!r}: write NAME=V1,V2 (a fusion parameter and its values)'
            raise ConfigError(msg)
        if name in {axis.name for axis in axes}:
            msg = f'--sweep {name} is given twice; give each parameter once with all its values'
            raise ConfigError(msg)
        axes.append(SweepAxis(name, parsed))
    return axes


def combinations(axes: Sequence[SweepAxis]) -> list[dict[str, Any]]:
    """Every combination of the axes' values, the last axis varying fastest."""
    return [
        dict(zip((axis.name for axis in axes), values, strict=True))
        for values in itertools.product(*(axis.values for axis in axes))
    ]


def setting_label(setting: dict[str, Any]) -> str:
    return ', '.join(f'{name}={value}' for name, value in setting.items())


@dataclass(frozen=True)
class SweepRow:
    """One method under one setting: the comparison's numbers (NaN: nothing to count)."""

    setting: dict[str, Any]
    method: str
    recall: float
    false_obstacle_rate: float
    collisions: float  # closed-loop trials with a collision (NaN: the method drove none)
    reached: float  # closed-loop trials that reached their goal
    trials: int  # closed-loop trials

    @classmethod
    def rows_of(cls, setting: dict[str, Any], result: EvaluationResult) -> list[SweepRow]:
        rows = []
        for name, method in result.methods.items():
            loop = method.closed_loop
            rows.append(
                cls(
                    dict(setting),
                    name,
                    method.scan.recall,
                    method.scan.false_obstacle_rate,
                    math.nan if loop is None else loop.collisions,
                    math.nan if loop is None else loop.reached,
                    0 if loop is None else loop.trials,
                )
            )
        return rows


@dataclass(frozen=True)
class SweepResult:
    """Every setting's evaluation result, in the order of `combinations`."""

    axes: list[SweepAxis]
    settings: list[dict[str, Any]]
    results: list[EvaluationResult]
    retried: int = 0

    def rows(self) -> list[SweepRow]:
        return [
            row
            for setting, result in zip(self.settings, self.results, strict=True)
            for row in SweepRow.rows_of(setting, result)
        ]


def run_sweep(
    settings: EvaluationSettings,
    axes: Sequence[SweepAxis],
    backend: Backend | None = None,
    progress: Progress | None = None,
) -> SweepResult:
    """Evaluate every combination of `axes` on `settings`' trials, on `backend`."""
    if not axes:
        msg = 'a sweep needs at least one --sweep NAME=V1,V2'
        raise ConfigError(msg)
    progress = progress or NullProgress()
    chosen = combinations(axes)
    evaluations = []
    for setting in chosen:
        changed = replace(settings, params={**settings.params, **setting})
        try:
            changed.fusion_base()  # a wrong name or value fails here, before any trial
        except ConfigError as err:
            msg = f'--sweep {setting_label(setting)}: {err}'
            raise ConfigError(msg) from err
        evaluations.append(Evaluation(changed))
    arguments = [(e.settings, job) for e in evaluations for job in e.jobs()]
    progress.start(f'{len(chosen)} settings: closed-loop and turning trials', len(arguments))
    done = run_tasks(_run_job, arguments, backend or LocalPool(), progress)
    progress.finish()
    parts = iter(done.results)
    for evaluation in evaluations:
        for _ in evaluation.jobs():
            evaluation.merge(next(parts))
    return SweepResult(
        list(axes), chosen, [e.result([]) for e in evaluations], retried=done.retried
    )


def _number(value: float, percent: bool = False) -> str:
    if math.isnan(value):
        return '-'
    return f'{100 * value:.1f} %' if percent else f'{value:g}'


def markdown(sweep: SweepResult) -> str:
    names = ', '.join(f'`{axis.name}`' for axis in sweep.axes)
    lines = [
        '# scanfuse sweep',
        '',
        (
            f'Every combination of {names} on the same seeded trials. Recall and false obstacles '
            "over the scored scans; collisions and goals reached over each method's closed-loop "
            'trials (- : the method drove none).'
        ),
        '',
        '| setting | method | recall | false obstacles | collisions | goals reached | trials |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    lines += [
        f'| {setting_label(row.setting)} | {row.method} | {_number(row.recall, percent=True)} | '
        f'{_number(row.false_obstacle_rate, percent=True)} | {_number(row.collisions)} | '
        f'{_number(row.reached)} | {row.trials} |'
        for row in sweep.rows()
    ]
    if sweep.retried:
        lines += ['', f'{sweep.retried} trial(s) ran again after their worker died (Ray).']
    return '\n'.join(lines) + '\n'


def to_json(sweep: SweepResult) -> str:
    def clean(value: Any) -> Any:
        return None if isinstance(value, float) and math.isnan(value) else value

    data = {
        'axes': [{'name': axis.name, 'values': list(axis.values)} for axis in sweep.axes],
        'rows': [{k: clean(v) for k, v in asdict(row).items()} for row in sweep.rows()],
        'retried': sweep.retried,
    }
    return json.dumps(data, indent=2)


def write_figure(sweep: SweepResult, path: Path) -> Path:
    """One panel per metric; per setting, a bar per method."""
    import matplotlib as mpl  # noqa: PLC0415

    mpl.use('Agg')
    import matplotlib.pyplot as plt  # noqa: PLC0415

    rows = sweep.rows()
    methods = list(dict.fromkeys(row.method for row in rows))
    labels = [setting_label(setting) for setting in sweep.settings]
    width = 0.8 / max(len(methods), 1)
    figure, panels = plt.subplots(len(METRICS), 1, figsize=(max(6.0, 1.6 * len(labels)), 11))
    for panel, (key, title) in zip(panels, METRICS, strict=True):
        for offset, method in enumerate(methods):
            values = [
                float(getattr(row, key)) * (100 if key in {'recall', 'false_obstacle_rate'} else 1)
                for setting in sweep.settings
                for row in rows
                if row.method == method and row.setting == setting
            ]
            positions = [i + (offset - (len(methods) - 1) / 2) * width for i in range(len(labels))]
            panel.bar(positions, values, width, label=method)
        unit = ' (%)' if key in {'recall', 'false_obstacle_rate'} else ' (trials)'
        panel.set_ylabel(title + unit)
        panel.set_xticks(range(len(labels)), labels, fontsize=8)
    panels[0].legend(fontsize=8)
    panels[-1].set_xlabel('setting')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def write_sweep(sweep: SweepResult, out: Path) -> list[Path]:
    """sweep.md, sweep.json, sweep.png and every setting's results.json under settings/."""
    out.mkdir(parents=True, exist_ok=True)
    folder = out / 'settings'
    folder.mkdir(exist_ok=True)
    written = [out / 'sweep.md', out / 'sweep.json']
    written[0].write_text(markdown(sweep), encoding='utf-8')
    written[1].write_text(to_json(sweep), encoding='utf-8')
    written.append(write_figure(sweep, out / 'sweep.png'))
    for index, result in enumerate(sweep.results):
        written.append(result.save(folder / f'{index:02d}.json'))
    return written


__all__ = [
    'SweepAxis',
    'SweepResult',
    'SweepRow',
    'combinations',
    'parse_sweeps',
    'run_sweep',
    'write_sweep',
]
