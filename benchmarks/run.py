"""`make bench` (`python -m benchmarks.run [section ...]` from the repository root): runs
every benchmark section on one core and prints one table.

Each `benchmarks/bench_*.py` module defines `run() -> list[Row]`.
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

# One core, as the targets are stated; set before numpy loads its BLAS.
for var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS', 'NUMBA_NUM_THREADS'):
    os.environ.setdefault(var, '1')

HERE = Path(__file__).resolve().parent

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402


def _format(seconds: float, unit: str = 's') -> str:
    if unit == 'share':
        return f'{seconds:.1%}'
    if seconds < 1e-3:
        return f'{seconds * 1e6:.1f} us'
    if seconds < 1.0:
        return f'{seconds * 1e3:.2f} ms'
    return f'{seconds:.2f} s'


def main() -> int:
    if hasattr(os, 'sched_setaffinity'):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    only = set(sys.argv[1:])
    console = Console()
    table = Table(title='scanfuse benchmarks (median, one core)')
    for column in ('section', 'benchmark', 'median', 'note'):
        table.add_column(column, justify='right' if column == 'median' else 'left')
    for path in sorted(HERE.glob('bench_*.py')):
        if only and path.stem.removeprefix('bench_') not in only:
            continue
        module = importlib.import_module(f'benchmarks.{path.stem}')
        with console.status(f'running {path.stem}'):
            rows = module.run()
        for row in rows:
            table.add_row(row.section, row.name, _format(row.median_s, row.unit), row.note)
        table.add_section()
    console.print(table)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
