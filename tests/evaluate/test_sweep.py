"""`scanfuse evaluate --sweep`: every combination on the same seeded trials, each row what a
separate run with that setting gives; one table (markdown, JSON) and one figure."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest

from scanfuse.cli import main
from scanfuse.cluster import LocalPool
from scanfuse.errors import ConfigError
from scanfuse.evaluate.runner import Evaluation
from scanfuse.evaluate.sweep import combinations, parse_sweeps, run_sweep, write_sweep
from tests.support.tiny_evaluation import tiny_evaluation


def test_a_two_by_two_sweep_equals_separate_runs(tmp_path):
    axes = parse_sweeps(['min_obstacle_height=0.03,0.06', 'max_obstacle_height=0.4,1.5'])
    sweep = run_sweep(tiny_evaluation(), axes, LocalPool(2))
    assert sweep.settings == [
        {'min_obstacle_height': 0.03, 'max_obstacle_height': 0.4},
        {'min_obstacle_height': 0.03, 'max_obstacle_height': 1.5},
        {'min_obstacle_height': 0.06, 'max_obstacle_height': 0.4},
        {'min_obstacle_height': 0.06, 'max_obstacle_height': 1.5},
    ]
    rows = sweep.rows()
    assert len(rows) == 4 * 2
    for setting, result in zip(sweep.settings, sweep.results, strict=True):
        alone = Evaluation(replace(tiny_evaluation(), params=setting))
        alone.run(1)
        expected = alone.result([])
        assert result.to_json() == expected.to_json()
        for row in (r for r in rows if r.setting == setting):
            method = expected.methods[row.method]
            assert method.closed_loop is not None
            assert math.isclose(row.recall, method.scan.recall) or (
                math.isnan(row.recall) and math.isnan(method.scan.recall)
            )
            assert row.false_obstacle_rate == method.scan.false_obstacle_rate
            assert row.collisions == method.closed_loop.collisions
            assert row.reached == method.closed_loop.reached
            assert row.trials == method.closed_loop.trials == 1
    written = write_sweep(sweep, tmp_path)
    assert {p.name for p in written} >= {'sweep.md', 'sweep.json', 'sweep.png'}
    assert (tmp_path / 'sweep.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    table = (tmp_path / 'sweep.md').read_text(encoding='utf-8')
    assert table.count('| min_obstacle_height=') == 8
    data = json.loads((tmp_path / 'sweep.json').read_text(encoding='utf-8'))
    assert [row['setting'] for row in data['rows'][::2]] == sweep.settings


def test_sweep_options_are_checked(tmp_path):
    assert combinations(parse_sweeps(['a=1', 'b=x,true'])) == [
        {'a': 1, 'b': 'x'},
        {'a': 1, 'b': True},
    ]
    with pytest.raises(ConfigError, match='write NAME=V1,V2'):
        parse_sweeps(['memory_time'])
    with pytest.raises(ConfigError, match='given twice'):
        parse_sweeps(['memory_time=1', 'memory_time=2'])
    with pytest.raises(ConfigError, match='--sweep min_obstacle_height=abc'):
        run_sweep(tiny_evaluation(), parse_sweeps(['min_obstacle_height=abc']))
    argv = ['evaluate', '--out', str(tmp_path), '--quick', '--sweep', 'no_such_parameter=1']
    assert main(argv) == 1
