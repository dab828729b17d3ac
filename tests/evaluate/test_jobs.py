"""`scanfuse evaluate --jobs N`: trials in parallel processes give the serial run's results."""

from __future__ import annotations

import numpy as np
import pytest

from scanfuse.cli import main
from scanfuse.errors import ConfigError
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings


def tiny() -> EvaluationSettings:
    return EvaluationSettings.quick(
        worlds=('barricade',),
        trials=0,
        methods=('lidar', 'obstacle', 'obstacle-no-memory'),
        closed_loop_methods=('lidar', 'obstacle'),
        turning=('turn-in-place',),
        time_limit=12.0,
        amr=(),
    )


def test_two_jobs_give_the_serial_result():
    serial, parallel = Evaluation(tiny()), Evaluation(tiny())
    serial.run(1)
    parallel.run(2)
    # Three jobs (two drives, one turn): merged in the serial order, every number the same.
    assert len(serial.jobs()) == 3
    assert parallel.result([]).to_json() == serial.result([]).to_json()
    assert [o.method for o in parallel.outcomes] == ['lidar', 'obstacle']
    assert set(parallel.maps) == set(serial.maps) == {'barricade-0'}
    for name, grid in serial.maps['barricade-0'].grids.items():
        assert np.array_equal(parallel.maps['barricade-0'].grids[name].log_odds, grid.log_odds)
    assert set(parallel.snapshots) == set(serial.snapshots)
    assert set(parallel.crash_maps) == set(serial.crash_maps) == {'barricade-0'}


def test_jobs_must_be_positive(tmp_path):
    with pytest.raises(ConfigError, match='--jobs must be 1 or more, got 0'):
        Evaluation(tiny()).run(0)
    assert main(['evaluate', '--out', str(tmp_path), '--quick', '--jobs', '0']) == 1
