"""Choosing a headless OpenGL for MuJoCo before it is imported."""

from __future__ import annotations

import os
import subprocess
import sys

from scanfuse.sim.headless_gl import choose_headless_gl, probe, probe_output


def test_mujoco_imports_and_steps_in_a_child_process():
    # Everything below relies on a working MuJoCo: without one these tests must fail, not
    # pass because every probe fails.
    script = (
        'import mujoco\n'
        'model = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><geom size="1"/>'
        "</worldbody></mujoco>')\n"
        'data = mujoco.MjData(model)\n'
        'mujoco.mj_step(model, data)\n'
        'print(model.ngeom)\n'
    )
    env = {key: value for key, value in os.environ.items() if key != 'MUJOCO_GL'}
    done = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, env=env, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ['1']


def test_an_unknown_backend_does_not_probe_fine_because_mujoco_refuses_it():
    # MuJoCo refuses MUJOCO_GL values it does not know at import: the child exits non-zero,
    # saying so (not, say, because MuJoCo is missing).
    works, stderr = probe_output('no-such-gl')
    assert works is False
    assert 'MUJOCO_GL' in stderr
    assert 'no-such-gl' in stderr
    assert probe('no-such-gl') is False


def test_an_explicit_choice_is_left_alone(monkeypatch):
    monkeypatch.setenv('MUJOCO_GL', 'osmesa')
    assert choose_headless_gl() == 'osmesa'


def test_nothing_changes_once_mujoco_is_imported():
    script = (
        'import os, mujoco\n'
        'os.environ.pop("MUJOCO_GL", None)\n'
        'from scanfuse.sim.headless_gl import choose_headless_gl\n'
        'print(choose_headless_gl(), os.environ.get("MUJOCO_GL"))\n'
    )
    env_out = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=True
    ).stdout
    assert env_out.split() == ['None', 'None']


def mujoco_imported_by(imports: str) -> bool:
    """Whether `imports` (one import statement) imports MuJoCo, in a fresh interpreter."""
    script = f'import sys\n{imports}\nprint("mujoco" in sys.modules)\n'
    out = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=True
    ).stdout
    return out.split() == ['True']


def test_importing_the_gl_choice_does_not_import_mujoco():
    # MuJoCo reads MUJOCO_GL once, at its import: choosing must come first.
    assert not mujoco_imported_by('from scanfuse.sim.headless_gl import choose_headless_gl')
    assert mujoco_imported_by('import mujoco')  # the check itself can tell


def test_the_entry_points_that_choose_a_gl_leave_mujoco_unimported_until_they_do():
    # `scanfuse demo` imports its module, then chooses (`run_demo`); the CLI modules choose
    # before importing the simulator. An import of MuJoCo on the way in would leave the
    # demo on ray casting, whose numbers differ slightly from the renderer's.
    assert not mujoco_imported_by('import scanfuse.app.demo, scanfuse.cli, scanfuse.evaluate.cli')
