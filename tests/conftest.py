"""Shared fixtures: where the real recorded data lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parent.parent


def _real_data_dir() -> Path:
    env = os.environ.get('SCANFUSE_REAL_DATA')
    return Path(env) if env else _REPO.parent / 'shared' / 'data' / 'real'


@pytest.fixture(scope='session')
def real_data() -> Path:
    """../shared/data/real (or $SCANFUSE_REAL_DATA); tests skip where it is absent."""
    path = _real_data_dir()
    if not path.is_dir():
        pytest.skip(f'real sensor data not found at {path} (set SCANFUSE_REAL_DATA)')
    return path
