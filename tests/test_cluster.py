"""`--cluster`: every trial (or bag) a task on a real Ray cluster on 127.0.0.1 (a head with one
worker process), merged as the serial run merges them; a worker killed mid-run; a batch of bags."""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import pytest
import ray.cloudpickle

from scanfuse.cli import main
from scanfuse.cluster import LocalPool, RayCluster, backend_of, run_tasks
from scanfuse.config import FusionConfig
from scanfuse.errors import ClusterError, ConfigError
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings
from scanfuse.evaluate.sweep import parse_sweeps, run_sweep
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.batch import BagOptions, fuse_bags, input_digest
from tests.support import ray_cluster
from tests.support.bag_batch import bag_folder, messages
from tests.support.ray_cluster import dying_job, ray_head
from tests.support.tiny_evaluation import tiny_evaluation

if TYPE_CHECKING:
    from collections.abc import Iterator

# The test's own function goes to the workers by value: they cannot import `tests`.
ray.cloudpickle.register_pickle_by_value(ray_cluster)


@pytest.fixture(scope='module')
def head() -> Iterator[str]:
    with ray_head(num_cpus=1) as address:
        yield address


@pytest.fixture(scope='module')
def serial() -> str:
    evaluation = Evaluation(tiny_evaluation())
    evaluation.run(1)
    return evaluation.result([]).to_json()


def test_the_cluster_gives_the_in_process_result(head, serial):
    evaluation = Evaluation(tiny_evaluation())
    evaluation.run(backend=RayCluster(head))
    assert len(evaluation.jobs()) == 2
    assert evaluation.retried == 0
    assert evaluation.result([]).to_json() == serial


def test_a_killed_worker_is_retried_and_every_trial_counted(head, serial, tmp_path):
    evaluation = Evaluation(tiny_evaluation())
    runner = functools.partial(dying_job, str(tmp_path))
    evaluation.run(backend=RayCluster(head, max_retries=1), job_runner=runner)
    # Every job's first attempt killed its worker: two markers, two runs again.
    assert len(list(tmp_path.iterdir())) == 2
    assert evaluation.retried == 2
    result = evaluation.result([])
    assert result.retried == 2
    # Apart from the count of retries, every number is the undisturbed in-process run's.
    assert dataclasses.replace(result, retried=0).to_json() == serial


def test_workers_lost_too_often_stop_the_run(head, tmp_path):
    runner = functools.partial(dying_job, str(tmp_path))
    with pytest.raises(ClusterError, match='lost its worker 1 times'):
        Evaluation(tiny_evaluation()).run(
            backend=RayCluster(head, max_retries=0), job_runner=runner
        )


def test_a_task_error_is_raised_as_itself(head):
    with pytest.raises(ConfigError, match='unknown method'):
        run_tasks(
            Evaluation,
            [(tiny_evaluation(),), (EvaluationSettings(methods=('sonar',)),)],
            RayCluster(head),
        )


def test_the_cli_says_when_the_cluster_cannot_be_reached(tmp_path, capsys):
    argv = ['evaluate', '--out', str(tmp_path / 'out'), '--quick', '--cluster', '127.0.0.1:1']
    assert main(argv) == 1
    assert 'ray start --head' in capsys.readouterr().err


def test_backend_options_are_checked():
    assert backend_of(2) == LocalPool(2)
    assert backend_of(1, 'auto', 5) == RayCluster('auto', 5)
    with pytest.raises(ConfigError, match='--cluster needs an address'):
        backend_of(1, ' ')
    with pytest.raises(ConfigError, match='--max-retries must be zero or more'):
        backend_of(1, 'local', -1)


def test_a_batch_of_bags_on_the_cluster(head, tmp_path):
    good, other, broken = bag_folder(tmp_path / 'in')
    before = {bag: input_digest(bag) for bag in (good, other, broken)}
    report = fuse_bags(
        tmp_path / 'in', tmp_path / 'out', BagOptions(FusionConfig()), RayCluster(head)
    )
    assert [o.input for o in report.failed] == [broken]
    assert report.retried == 0
    for bag in (good, other):
        single = fuse_bag(bag, tmp_path / f'single-{bag.name}')
        assert messages(tmp_path / 'out' / bag.name) == messages(single.output)
    assert {bag: input_digest(bag) for bag in before} == before


def test_a_sweep_on_the_cluster_gives_the_local_sweep(head):
    axes = parse_sweeps(['min_obstacle_height=0.03,0.06'])
    local = run_sweep(tiny_evaluation(), axes, LocalPool(1))
    remote = run_sweep(tiny_evaluation(), axes, RayCluster(head))
    assert remote.settings == local.settings
    assert [r.to_json() for r in remote.results] == [r.to_json() for r in local.results]
