"""Where independent tasks run: a local process pool (the default) or a Ray cluster.

One function, `run_tasks`, runs `function(*arguments)` for every argument tuple and returns
the results in the order given, whatever order they finished in: the evaluation merges them
in that order, so a run on a pool or a cluster gives the serial run's numbers. The caller
chooses the place with a `Backend`: `LocalPool(jobs)` or `RayCluster(address)`.

On a Ray cluster a task whose worker process (or machine) died is submitted again, up to
`max_retries` times, and counted; an exception raised by the task itself is not retried (the
same inputs would raise it again) and stops the run, as it does locally. Ray is imported only
here and only when a cluster is asked for (`pip install 'scanfuse[cluster]'`).
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from scanfuse.errors import ClusterError, ConfigError
from scanfuse.progress import NullProgress, Progress

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

R = TypeVar('R')

INSTALL_HINT = "pip install 'scanfuse[cluster]'"
DEFAULT_RETRIES = 3


@dataclass(frozen=True)
class TaskRun(Generic[R]):
    """Every task's result in the order submitted, and how many attempts were made again."""

    results: list[R]
    retried: int = 0  # submissions again after a worker died


@dataclass(frozen=True)
class LocalPool:
    """`jobs` processes on this machine (spawned: no GL context or numba state forked);
    one job runs in this process."""

    jobs: int = 1

    def describe(self) -> str:
        return f'{self.jobs} local process{"es" if self.jobs != 1 else ""}'


@dataclass(frozen=True)
class RayCluster:
    """A Ray cluster: `address` is `host:port` of its head, `auto` (a cluster started on this
    machine with `ray start`), or `local` (a cluster of this machine for this run only)."""

    address: str
    max_retries: int = DEFAULT_RETRIES

    def describe(self) -> str:
        return f'Ray cluster {self.address}'


Backend = LocalPool | RayCluster


def backend_of(
    jobs: int = 1, cluster: str | None = None, max_retries: int | None = None
) -> Backend:
    """The backend the CLI's `--jobs` and `--cluster` options ask for (checked)."""
    if jobs < 1:
        msg = f'--jobs must be 1 or more, got {jobs}'
        raise ConfigError(msg)
    if cluster is None:
        return LocalPool(jobs)
    address = cluster.strip()
    if not address:
        msg = '--cluster needs an address: HOST:PORT of the Ray head, auto, or local'
        raise ConfigError(msg)
    retries = DEFAULT_RETRIES if max_retries is None else max_retries
    if retries < 0:
        msg = f'--max-retries must be zero or more, got {retries}'
        raise ConfigError(msg)
    return RayCluster(address, retries)


def run_tasks(
    function: Callable[..., R],
    arguments: Sequence[tuple[Any, ...]],
    backend: Backend,
    progress: Progress | None = None,
) -> TaskRun[R]:
    """`function(*args)` for every `args` in `arguments`; results in the same order.

    `progress` advances by one per finished task (its `start` and `finish` are the caller's).
    """
    progress = progress or NullProgress()
    if isinstance(backend, RayCluster):
        return _run_on_ray(function, arguments, backend, progress)
    if backend.jobs == 1 or len(arguments) <= 1:
        results = []
        for args in arguments:
            results.append(function(*args))
            progress.advance()
        return TaskRun(results)
    context = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(max_workers=backend.jobs, mp_context=context) as pool:
        futures = [pool.submit(function, *args) for args in arguments]
        for _ in as_completed(futures):
            progress.advance()
        return TaskRun([future.result() for future in futures])


def _run_on_ray(
    function: Callable[..., R],
    arguments: Sequence[tuple[Any, ...]],
    cluster: RayCluster,
    progress: Progress,
) -> TaskRun[R]:
    from scanfuse import ray_api  # noqa: PLC0415

    with ray_api.connected(cluster.address):
        remote = ray_api.remote(function)
        pending = {remote.submit(*args): index for index, args in enumerate(arguments)}
        attempts = dict.fromkeys(range(len(arguments)), 0)
        results: dict[int, R] = {}
        retried = 0
        while pending:
            ref = ray_api.wait_one(list(pending))
            index = pending.pop(ref)
            try:
                results[index] = ray_api.get(ref)
            except ray_api.WorkerLost as err:
                if attempts[index] >= cluster.max_retries:
                    msg = (
                        f'task {index + 1} of {len(arguments)} lost its worker '
                        f"{attempts[index] + 1} times ({err}); check the cluster's machines "
                        '(`ray status`) or raise --max-retries'
                    )
                    raise ClusterError(msg) from err
                attempts[index] += 1
                retried += 1
                pending[remote.submit(*arguments[index])] = index
                continue
            progress.advance()
        return TaskRun([results[index] for index in range(len(arguments))], retried)


__all__ = [
    'Backend',
    'LocalPool',
    'RayCluster',
    'TaskRun',
    'backend_of',
    'run_tasks',
]
