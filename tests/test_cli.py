"""The `scanfuse` entry point: exit codes and one clean line for known errors."""

from __future__ import annotations

import subprocess
import sys

from scanfuse.cli import main


def test_help_exits_zero(capsys):
    assert main(['--help']) == 0
    assert 'bag' in capsys.readouterr().out


def test_usage_error_exits_two():
    assert main(['bag']) == 2


def test_known_error_is_one_line_and_exit_one(tmp_path, capsys):
    assert main(['bag', str(tmp_path / 'missing'), str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert 'does not exist' in err
    assert 'Traceback' not in err


def test_missing_simulator_names_the_extra(tmp_path):
    # `None` in sys.modules makes `import mujoco` fail as if it were not installed.
    script = (
        'import sys\n'
        'sys.modules["mujoco"] = None\n'
        'from scanfuse.cli import main\n'
        f'raise SystemExit(main(["simulate", "--depth-backend", "multiray", "--out", '
        f'"{tmp_path / "run.mcap"}"]))\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=False
    )
    assert done.returncode == 1
    assert "pip install 'scanfuse[sim]'" in done.stderr
