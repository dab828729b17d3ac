"""Test support: analytic scenes and renderers, synthetic bags, DDS peers, reference code.

Imported by the tests and the benchmarks (the repository root is on their path: pytest's
rootdir, and benchmarks/run.py); never by the installed package.
"""

import os
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[2]


def with_repository_on_path(env: dict[str, str]) -> dict[str, str]:
    """`env` for a child process that runs `python -m tests.support.<module>`."""
    existing = env.get('PYTHONPATH')
    path = str(REPOSITORY) if not existing else os.pathsep.join([str(REPOSITORY), existing])
    return {**env, 'PYTHONPATH': path}
