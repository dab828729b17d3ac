"""Compiled kernels: numba.njit with its on-disk cache, so a node start loads machine code.

numba keeps the cache in __pycache__ beside the kernel's module, or under the user's cache
directory (~/.cache/numba, or $NUMBA_CACHE_DIR) when the installed package is read-only.
With neither writable it cannot cache at all: the kernel is compiled at start then. Without
numba (a dependency, so only in a broken install) the plain Python function runs: the same
numbers, slower.
"""

from __future__ import annotations

from typing import Any, TypeVar

F = TypeVar('F')


def compiled(function: F, **options: Any) -> F:
    """`function` compiled by numba (nogil, cached, plus `options` such as parallel)."""
    try:
        import numba  # noqa: PLC0415
    except ImportError:  # pragma: no cover - numba is a dependency; this is the fallback
        return function
    try:
        kernel: F = numba.njit(cache=True, nogil=True, **options)(function)
    except RuntimeError:  # pragma: no cover - "no locator available": nowhere to write
        kernel = numba.njit(nogil=True, **options)(function)
    return kernel
