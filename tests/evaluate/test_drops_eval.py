"""Falls in results and report, false drop slots, and the drop worlds' trials."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from scanfuse.config import FusionConfig, Method
from scanfuse.evaluate.closed_loop import FIXED_GOALS, TrialOutcome
from scanfuse.evaluate.drops import false_drop_slots, reports_drops
from scanfuse.evaluate.metrics import ScanTally
from scanfuse.evaluate.report import headline_rows, markdown
from scanfuse.evaluate.results import ClosedLoopSummary, EvaluationResult, MethodResult
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings
from scanfuse.sim.worlds import make_world

OUTCOME = TrialOutcome(
    trial='ledge-0',
    method='lidar',
    collided=False,
    first_contact_kind='',
    first_contact_time=math.nan,
    reached=False,
    final_distance=2.5,
    path_length=2.5,
    duration=8.7,
    planned_length=4.0,
    fell=True,
    fall_time=7.7,
)


def test_falls_round_trip_through_results_json(tmp_path):
    safe = replace(OUTCOME, method='lidar', trial='hole-0', fell=False, fall_time=math.nan)
    outcomes = [OUTCOME, safe]
    loop = ClosedLoopSummary.of(outcomes)
    assert (loop.trials, loop.falls, loop.collisions) == (2, 1, 0)
    method = MethodResult(
        'lidar',
        'LiDAR alone',
        ScanTally().summary(),
        {},
        {},
        loop,
        drop_free_slots=4000,
        false_drop_slots=1,
    )
    settings = {'worlds': ['ledge', 'hole'], 'trials': 0, 'resolution': [256, 144], 'noise': True}
    result = EvaluationResult(settings, {'lidar': method}, outcomes)
    loaded = EvaluationResult.load(result.save(tmp_path / 'results.json'))
    loaded_loop = loaded.methods['lidar'].closed_loop
    assert loaded_loop is not None
    assert (loaded_loop.trials, loaded_loop.falls, loaded_loop.collisions) == (2, 1, 0)
    assert [t.fell for t in loaded.trials] == [True, False]
    assert loaded.trials[0].fall_time == pytest.approx(7.7)
    assert math.isnan(loaded.trials[1].fall_time)
    assert loaded.methods['lidar'].false_drop_rate == pytest.approx(1 / 4000)
    assert loaded.headline()['lidar']['falls'] == 1
    # The falls column sits between collisions and goals reached.
    assert headline_rows(loaded)[0][-3:] == ['0/2', '1/2', '0/2']
    report = markdown(loaded)
    assert '| collisions | falls | goals reached |' in report
    assert '## False drop slots per method' in report
    assert '| lidar | 4000 | 1 | 0.03 % |' in report


def test_a_results_file_without_falls_reads_as_no_falls():
    text = EvaluationResult({}, {}, [replace(OUTCOME, fell=False, fall_time=math.nan)]).to_json()
    data = json.loads(text)
    for trial in data['trials']:
        del trial['fell'], trial['fall_time']
    assert EvaluationResult.from_json(json.dumps(data)).trials[0].fell is False


def test_false_drop_slots_are_what_drops_alone_moved_short_of_the_truth():
    # Truth per slot: a wall 3 m away everywhere. Tolerance 0.05 m + 2 %: 0.11 m at 3 m.
    truth = np.full(5, 3.0, dtype=np.float32)
    without = np.array([3.0, 1.0, 3.0, 3.0, np.nan], dtype=np.float32)
    with_drops = np.array(
        [
            1.5,  # drops put a point at 1.5 m where there was floor: false drop
            1.0,  # short of the truth, but so it is without drops (floor noise): not a drop
            2.95,  # 5 cm short: within the tolerance of the truth
            3.0,  # the same as without drops
            1.5,  # nothing to compare with (NaN without drops): never counted
        ],
        dtype=np.float32,
    )
    mask = false_drop_slots(with_drops, without, truth)
    assert mask.tolist() == [True, False, False, False, False]
    # Drops that move a reading closer by less than the tolerance are not false drops either.
    assert not false_drop_slots(np.float32([0.97]), np.float32([1.0]), np.float32([3.0])).any()


def test_only_the_obstacle_method_with_drops_on_reports_drops():
    obstacle = FusionConfig(method=Method.OBSTACLE)
    assert reports_drops(obstacle) == ('detect_drops' in FusionConfig.model_fields)
    assert not reports_drops(obstacle, fuses=False)  # `lidar`: the driver's scan, no fusion
    assert not reports_drops(FusionConfig(method=Method.ROW))
    if 'detect_drops' in FusionConfig.model_fields:
        assert not reports_drops(obstacle.with_changes(detect_drops=False))


def test_drop_world_goals_lie_on_the_floor_across_the_drop_from_the_start():
    for name in ('ledge', 'stairs', 'hole'):
        world = make_world(name)
        goal = FIXED_GOALS[name]
        start = np.array([world.start.x, world.start.y])
        assert not any(drop.contains(*goal) for drop in world.drops)
        # The straight line from the start to the goal passes over the drop.
        line = start + np.linspace(0.0, 1.0, 200)[:, None] * (np.array(goal) - start)
        assert any(drop.contains(*point) for point in line for drop in world.drops), name


def test_in_the_ledge_world_lidar_falls_and_obstacle_stops_and_arrives():
    settings = EvaluationSettings.quick(
        worlds=('ledge',),
        trials=0,
        turning=(),
        methods=('lidar', 'obstacle'),
        closed_loop_methods=('lidar', 'obstacle'),
        amr=(),
    )
    evaluation = Evaluation(settings)
    evaluation.run()
    outcomes = {o.method: o for o in evaluation.outcomes}
    assert outcomes['lidar'].fell
    assert not outcomes['lidar'].reached
    assert not outcomes['obstacle'].fell
    assert outcomes['obstacle'].reached
    # The dock edge is a low obstacle of its own kind: the LiDAR plane never sees it.
    result = evaluation.result([])
    assert result.methods['lidar'].scan.recall_by_kind['ledge'] < 0.05
    assert result.methods['obstacle'].scan.recall_by_kind['ledge'] > 0.3
