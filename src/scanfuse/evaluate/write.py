"""Run an evaluation and write what it leaves: figures, maps, configuration, results, report.

The steps of `scanfuse evaluate`: run (`runner.Evaluation`), then write (`report` for the
text and figures). `runner` knows nothing of the report, so the two do not import each
other.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict
from typing import TYPE_CHECKING

import yaml

from scanfuse.evaluate import report
from scanfuse.evaluate.closed_loop import TURNING_TRIALS
from scanfuse.evaluate.mapping import save_map
from scanfuse.evaluate.runner import (
    Evaluation,
    EvaluationSettings,
    base_config,
    make_simulation,
    terrain_simulation,
)

if TYPE_CHECKING:
    from pathlib import Path

    from scanfuse.cluster import Backend
    from scanfuse.config import FusionConfig
    from scanfuse.evaluate.results import EvaluationResult
    from scanfuse.progress import Progress


def write_outputs(evaluation: Evaluation, out: Path, config: FusionConfig) -> EvaluationResult:
    """Figures, maps, the configuration, results.json and report.md in `out`."""

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


def run_evaluation(
    out: Path,
    settings: EvaluationSettings,
    progress: Progress | None = None,
    jobs: int = 1,
    backend: Backend | None = None,
) -> EvaluationResult:
    """Run the evaluation (on `backend`, else `jobs` local processes) and write everything
    into `out`."""
    evaluation = Evaluation(settings, progress)
    evaluation.run(jobs, backend=backend)
    if not evaluation.trials and not settings.turning and evaluation.terrain_specs:
        # Only terrain trials: the sprung robot as its parameters describe it.
        reference, config, _ = terrain_simulation(evaluation.terrain_specs[0], settings)
        reference.close()
        return write_outputs(evaluation, out, config)
    first = evaluation.trials[0] if evaluation.trials else TURNING_TRIALS[settings.turning[0]]
    reference = make_simulation(first, settings)
    try:
        config = base_config(reference, settings)
    finally:
        reference.close()
    return write_outputs(evaluation, out, config)
