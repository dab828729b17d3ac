"""The smallest evaluation whose results mean something, for the sweep and cluster tests."""

from __future__ import annotations

from scanfuse.evaluate.runner import EvaluationSettings


def tiny_evaluation() -> EvaluationSettings:
    """Two jobs: 4 s drives of the barricade world by `lidar` and by `obstacle`."""
    return EvaluationSettings.quick(
        worlds=('barricade',),
        trials=0,
        methods=('lidar', 'obstacle'),
        closed_loop_methods=('lidar', 'obstacle'),
        turning=(),
        time_limit=4.0,
        amr=(),
    )
