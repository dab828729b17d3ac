"""The few parts of Ray scanfuse uses, typed, behind one import that says how to install it.

Ray is optional (`pip install 'scanfuse[cluster]'`); importing this module without it raises
`ClusterError` naming that command. Everything Ray-shaped stays here: `cluster` runs tasks
through these functions and never imports Ray itself.
"""

from __future__ import annotations

import logging
import socket
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from scanfuse.errors import ClusterError

try:
    import ray
    import ray.exceptions
except ImportError as err:  # pragma: no cover - `make test` installs Ray
    msg = f"--cluster needs Ray, which is not installed: pip install 'scanfuse[cluster]' ({err})"
    raise ClusterError(msg) from err

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

R = TypeVar('R')

# What a lost worker or machine raises on `get`: the task itself did not fail, it may run again.
WorkerLost: tuple[type[BaseException], ...] = tuple(
    error
    for error in (
        getattr(ray.exceptions, name, None)
        for name in ('WorkerCrashedError', 'NodeDiedError', 'ObjectLostError', 'OwnerDiedError')
    )
    if isinstance(error, type) and issubclass(error, BaseException)
)


class Ref(Generic[R]):
    """A submitted task's result to come (a Ray ObjectRef), hashable, typed by its result."""

    __slots__ = ('object_ref',)

    def __init__(self, object_ref: Any) -> None:
        self.object_ref = object_ref

    def __hash__(self) -> int:
        return hash(self.object_ref)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Ref) and other.object_ref == self.object_ref


def _apply(function: Callable[..., R], *args: Any) -> R:
    return function(*args)


class Remote(Generic[R]):
    """A callable (a function, a `functools.partial`) run as Ray tasks; every submission runs
    once (retries are the caller's, who counts them)."""

    def __init__(self, function: Callable[..., R]) -> None:
        self._function = function
        self._remote = ray.remote(max_retries=0, retry_exceptions=False)(_apply)

    def submit(self, *args: Any) -> Ref[R]:
        return Ref(self._remote.remote(self._function, *args))


def remote(function: Callable[..., R]) -> Remote[R]:
    return Remote(function)


def wait_one(refs: list[Ref[R]]) -> Ref[R]:
    """The first of `refs` to finish (its result or its failure)."""
    by_ref = {ref.object_ref: ref for ref in refs}
    ready, _ = ray.wait(list(by_ref), num_returns=1)
    return by_ref[ready[0]]


def get(ref: Ref[R]) -> R:
    """The task's result; a task's own exception is raised as itself (as the local pool
    does), a lost worker as one of `WorkerLost`."""
    try:
        result: R = ray.get(ref.object_ref)
    except ray.exceptions.RayTaskError as err:
        cause = err.cause if isinstance(getattr(err, 'cause', None), BaseException) else None
        if cause is not None and not isinstance(cause, WorkerLost):
            raise cause from err
        raise
    return result


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """A `host:port` head answers on its port (Ray itself retries a refused one for minutes)."""
    host, colon, port = address.rpartition(':')
    if not colon or not port.isdigit() or '://' in host:
        return  # `auto`, `local`, `ray://...`: Ray's own check
    with socket.create_connection((host or '127.0.0.1', int(port)), timeout=timeout):
        pass


@contextmanager
def connected(address: str) -> Iterator[None]:
    """Connected to the Ray cluster at `address` (`host:port`, `auto`, or `local`: one started
    for this run on this machine), disconnected on the way out."""
    if ray.is_initialized():
        yield
        return
    options: dict[str, Any] = {'logging_level': logging.WARNING, 'log_to_driver': False}
    if address == 'local':
        options['include_dashboard'] = False
    else:
        options['address'] = address
    try:
        _check_reachable(address)
        ray.init(**options)
    except (OSError, RuntimeError, ValueError) as err:
        msg = (
            f'cannot connect to the Ray cluster at {address!r} ({err}); start its head with '
            '`ray start --head --port 6379` and pass --cluster HEAD_IP:6379, or pass '
            '--cluster local for a cluster of this machine alone'
        )
        raise ClusterError(msg) from err
    try:
        yield
    finally:
        ray.shutdown()


__all__ = ['Ref', 'Remote', 'WorkerLost', 'connected', 'get', 'remote', 'wait_one']
