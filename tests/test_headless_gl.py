"""Choosing a headless OpenGL for MuJoCo before it is imported."""

from __future__ import annotations

import subprocess
import sys

from scanfuse.headless_gl import choose_headless_gl, probe


def test_an_unknown_backend_does_not_probe_fine():
    # MuJoCo refuses MUJOCO_GL values it does not know at import: the child exits non-zero.
    assert probe('no-such-gl') is False


def test_an_explicit_choice_is_left_alone(monkeypatch):
    monkeypatch.setenv('MUJOCO_GL', 'osmesa')
    assert choose_headless_gl() == 'osmesa'


def test_nothing_changes_once_mujoco_is_imported():
    script = (
        'import os, mujoco\n'
        'os.environ.pop("MUJOCO_GL", None)\n'
        'from scanfuse.headless_gl import choose_headless_gl\n'
        'print(choose_headless_gl(), os.environ.get("MUJOCO_GL"))\n'
    )
    env_out = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=True
    ).stdout
    assert env_out.split() == ['None', 'None']
