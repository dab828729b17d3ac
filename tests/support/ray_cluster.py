"""A real Ray cluster on 127.0.0.1 for the tests: a head started with `ray start --block` in
a process group of its own, stopped by signalling that group (never `ray stop`, which would
stop every Ray cluster of the machine); and a task that kills its own worker once."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

    from scanfuse.evaluate.runner import EvaluationPart, EvaluationSettings, Job

START_TIMEOUT = 240.0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        port: int = probe.getsockname()[1]
    return port


@contextmanager
def ray_head(num_cpus: int = 1) -> Iterator[str]:
    """A Ray head on 127.0.0.1 running tasks in `num_cpus` worker processes; its address."""
    ray = Path(sys.executable).parent / 'ray'
    port = _free_port()
    temp = tempfile.mkdtemp(prefix='sfray', dir='/tmp')  # short: Ray's sockets live there
    env = {**os.environ, 'RAY_USAGE_STATS_ENABLED': '0', 'RAY_AUTH_MODE': 'disabled'}
    command = [
        str(ray), 'start', '--head', '--block',
        '--node-ip-address', '127.0.0.1', '--port', str(port),
        '--num-cpus', str(num_cpus), '--num-gpus', '0',
        '--include-dashboard', 'false', '--disable-usage-stats', '--temp-dir', temp,
    ]  # fmt: skip
    log = Path(temp) / 'head.log'
    with log.open('wb') as output:
        head = subprocess.Popen(
            command,
            env=env,
            start_new_session=True,
            stdout=output,
            stderr=subprocess.STDOUT,
        )
    address = f'127.0.0.1:{port}'
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            status = subprocess.run(
                [str(ray), 'status', '--address', address],
                env=env,
                capture_output=True,
                check=False,
            )
            if status.returncode == 0:
                break
            if head.poll() is not None or time.monotonic() > deadline:
                why = 'exited' if head.poll() is not None else f'not up in {START_TIMEOUT} s'
                said = log.read_text(encoding='utf-8', errors='replace')[-3000:]
                msg = f'the Ray head on {address} did not start ({why}): {said} {status.stderr!r}'
                raise RuntimeError(msg)
            time.sleep(1.0)
        yield address
    finally:
        _stop(head)
        shutil.rmtree(temp, ignore_errors=True)


def _stop(head: subprocess.Popen[bytes]) -> None:
    """SIGTERM to the head's process group (every Ray process it started), then SIGKILL."""
    group = head.pid  # start_new_session: the group's id is the head's pid
    try:
        os.killpg(group, signal.SIGTERM)
        head.wait(timeout=5)
    except subprocess.TimeoutExpired:
        pass
    except ProcessLookupError:
        return
    time.sleep(1.0)
    with suppress(ProcessLookupError):
        os.killpg(group, signal.SIGKILL)
    head.wait(timeout=10)


def dying_job(markers: str, settings: EvaluationSettings, job: Job) -> EvaluationPart:
    """`_run_job`, but the first attempt of each job kills its own worker process (SIGKILL:
    as a machine lost or a process killed by the kernel) after leaving a marker file."""
    from scanfuse.evaluate.runner import _run_job

    marker = Path(markers) / f'{job[0]}-{job[1]}'.replace('/', '_')
    if not marker.exists():
        marker.write_text(str(os.getpid()), encoding='utf-8')
        os.kill(os.getpid(), signal.SIGKILL)
    return _run_job(settings, job)
