"""Regression tests of issue 26 through the `scanfuse` command line: hostile parameter files
and poor errors are one clean line and exit 1, found before any work is done."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from scanfuse.cli import main
from tests.support.synthetic import Scene, write_scene_bag

LAUGHS = '\n'.join(
    [
        'a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]',
        *(
            f'{name}: &{name} [{", ".join([f"*{previous}"] * 10)}]'
            for previous, name in zip('abcdefgh', 'bcdefghi', strict=True)
        ),
        'scanfuse:',
        '  ros__parameters:',
        '    scan_topic: *i',
        '',
    ]
)


def hostile_file(tmp_path, kind: str) -> str:
    """A parameter file that is no parameter file: bytes, depth, aliases, or endless."""
    if kind == 'dev-zero':
        return '/dev/zero'
    path = tmp_path / f'{kind}.yaml'
    if kind == 'not-utf-8':
        path.write_bytes(b'scanfuse:\n  ros__parameters:\n    scan_topic: /sc\xffan\n')
    elif kind == 'nested':
        path.write_text('[' * 20_000 + ']' * 20_000 + '\n', encoding='utf-8')
    else:
        path.write_text(LAUGHS, encoding='utf-8')
    return str(path)


PROBLEMS = {
    'not-utf-8': 'is not UTF-8 text',
    'nested': 'nests more than 32 levels deep',
    'billion-laughs': 'uses a YAML alias',
    'dev-zero': 'is larger than 1024 KiB',
}


@pytest.mark.parametrize('kind', list(PROBLEMS))
@pytest.mark.parametrize('command', ['bag', 'simulate', 'evaluate'])
def test_a_hostile_parameter_file_is_one_clean_line(tmp_path, capsys, command, kind):
    """Issue 26.10: non-UTF-8 bytes, YAML nested 20 000 deep, a billion-laughs file under a
    real key (2.9 GB expanded) and `--params /dev/zero` (3.4 GB read) ended `bag`, `simulate`
    and `evaluate` with a traceback, or after gigabytes; now one line each, exit 1."""
    params = hostile_file(tmp_path, kind)
    if command == 'bag':
        source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
        argv = ['bag', str(source), str(tmp_path / 'out'), '--params', params]
    else:
        argv = [command, '--out', str(tmp_path / 'out'), '--params', params]
    start = time.monotonic()
    assert main(argv) == 1
    assert time.monotonic() - start < 30.0
    err = capsys.readouterr().err
    assert err.startswith('error: ')
    assert PROBLEMS[kind] in ' '.join(err.split())
    assert 'Traceback' not in err
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('duration', ['inf', 'nan', '0', '-1'])
def test_simulate_refuses_a_duration_that_is_not_a_positive_finite_time(tmp_path, capsys, duration):
    """Issue 26.11: `simulate --duration inf` ended in a traceback."""
    argv = ['simulate', '--out', str(tmp_path / 'run.mcap'), '--duration', duration]
    assert main(argv) == 1
    err = ' '.join(capsys.readouterr().err.split())
    assert f'--duration must be more than 0 and at most 86400 s, got {float(duration)}' in err
    assert not (tmp_path / 'run.mcap').exists()


def test_evaluate_refuses_an_existing_file_as_out_before_any_work(tmp_path, capsys):
    """Issue 26.11: `evaluate --out EXISTING_FILE` failed with a traceback after two minutes
    of trials; the output is checked first now."""
    existing = tmp_path / 'results'
    existing.write_text('keep me', encoding='utf-8')
    start = time.monotonic()
    assert main(['evaluate', '--quick', '--out', str(existing)]) == 1
    assert time.monotonic() - start < 10.0
    err = ' '.join(capsys.readouterr().err.split())
    assert f'error: --out {existing} exists and is not a folder' in err
    assert existing.read_text(encoding='utf-8') == 'keep me'
    assert main(['evaluate', '--quick', '--out', str(existing / 'below')]) == 1
    assert 'is not a folder' in capsys.readouterr().err


@pytest.mark.parametrize(
    ('sources', 'where'),
    [
        ({'lidars': ['front', 'front']}, 'lidars'),
        ({'lidars': ['front'], 'clouds': ['front']}, 'lidars and clouds'),
    ],
)
def test_a_source_name_listed_twice_is_named(tmp_path, capsys, sources, where):
    """Issue 26.11: `lidars: [a, a]`, or one name under lidars and clouds, said "Field
    required" (the second listing found its section taken); now the duplicate is named."""
    params = tmp_path / 'params.yaml'
    values = {**sources, 'front': {'topic': '/scan'}}
    params.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}), encoding='utf-8')
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 1
    err = ' '.join(capsys.readouterr().err.split())
    assert f"source name 'front' is listed twice ({where})" in err
    assert 'Field required' not in err


def _catches_sigterm(pid: int) -> bool:
    """Whether process `pid` has a handler for SIGTERM (/proc's SigCgt mask)."""
    for line in Path(f'/proc/{pid}/status').read_text(encoding='utf-8').splitlines():
        if line.startswith('SigCgt:'):
            return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    return False


@pytest.mark.skipif(
    not Path('/proc/self/status').exists(), reason='reads the signal mask from /proc (Linux)'
)
@pytest.mark.parametrize('delay', [0.05, 0.2, 0.4])
def test_sigterm_in_the_first_second_of_start_up_exits_143(tmp_path, delay):
    """Issue 26.12: SIGTERM while `scanfuse` was still starting (importing numpy and its
    kernels, about a second) killed it (-15) instead of exit code 143. The signal is sent
    `delay` s after the start, or once the command catches it, at the latest 0.5 s in (the
    import alone took 0.7 s)."""
    command = Path(sys.executable).with_name('scanfuse')
    assert command.exists(), f'no {command}: install the package (make test installs it)'
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    child = subprocess.Popen(
        [str(command), 'bag', str(source), str(tmp_path / 'out')],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    start = time.monotonic()
    while time.monotonic() - start < 0.5 and not (
        time.monotonic() - start >= delay and _catches_sigterm(child.pid)
    ):
        time.sleep(0.005)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 128 + signal.SIGTERM, err
    assert 'Traceback' not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in']
