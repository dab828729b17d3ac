"""Every Python block of README.md and docs/ runs as written, from the repository root
(where a newcomer runs it: the examples name examples/scanfuse.yaml)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.support import REPOSITORY, with_repository_on_path

BLOCK = re.compile(r'^```python\n(.*?)^```', re.DOTALL | re.MULTILINE)
PAGES = [REPOSITORY / 'README.md', *sorted((REPOSITORY / 'docs').rglob('*.md'))]
BLOCKS = [
    pytest.param(code, id=f'{page.relative_to(REPOSITORY)}:{number}')
    for page in PAGES
    for number, code in enumerate(BLOCK.findall(page.read_text(encoding='utf-8')), start=1)
]


def test_the_python_page_has_python_blocks():
    # If the pattern above stopped matching, the test below would check nothing.
    assert any(str(block.id).startswith('docs/python.md') for block in BLOCKS)


@pytest.mark.parametrize('code', BLOCKS)
def test_a_python_block_runs_as_written(code, tmp_path):
    import os

    script = tmp_path / 'block.py'
    script.write_text(code, encoding='utf-8')
    done = subprocess.run(
        [sys.executable, str(script)],
        cwd=REPOSITORY,
        env=with_repository_on_path(dict(os.environ)),
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
