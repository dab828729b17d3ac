"""colcon's way into the package; pip builds from pyproject.toml and gets nothing from here.

colcon (the ament_python build type) runs `setup.py` with the system's setuptools: 59.6.0 on
Ubuntu 22.04 (Humble), 68.1.2 on Ubuntu 24.04 (Jazzy). Neither can read pyproject.toml's
`[project]` table as written (59.6 reads no `[project]` at all; before 77 the SPDX string
`license = "Apache-2.0"` is refused), so for colcon this file hands setuptools the metadata
itself, read from pyproject.toml, and keeps setuptools from reading that file. In colcon's
subprocesses the variable COLCON is set (colcon-core sets it for exactly that), and only then
does this add what a ROS 2 package installs beside its Python code: the ament index marker,
package.xml, the launch file and the parameter files under share/scanfuse, and the
`scanfuse_node` executable (setup.cfg sends executables to lib/scanfuse, where `ros2 run`
looks). `colcon build` and `colcon build --symlink-install` both work under setuptools 59.6.0,
68.1.2 and current ones (tests/test_package.py).
"""

from __future__ import annotations

import ast
import os
import re
from pathlib import Path
from typing import Any

from setuptools import find_packages, setup
from setuptools.dist import Distribution

PACKAGE = 'scanfuse'
NODE_EXECUTABLE = 'scanfuse_node = scanfuse.__main__:node_entry'
HERE = Path(__file__).resolve().parent
TABLE = re.compile(r'^\[([^\]]+)\]\s*$')
KEY_VALUE = re.compile(r'^([A-Za-z0-9_-]+)\s*=\s*(.*)$')


def read_project_tables(text: str) -> dict[str, dict[str, Any]]:
    """The `[project]` and `[project.scripts]` tables of pyproject.toml.

    Humble's Python (3.10) has no TOML reader in its standard library and setuptools 59.6
    vendors none, so this reads the subset these two tables use: keys whose values are
    strings or arrays of strings (one line or several), and comment lines.
    tests/test_package.py checks it against tomllib on the real file.
    """
    tables: dict[str, dict[str, Any]] = {'project': {}, 'project.scripts': {}}
    current: dict[str, Any] | None = None
    lines = iter(text.splitlines())
    for line in lines:
        stripped = line.strip()
        header = TABLE.match(stripped)
        if header:
            current = tables.get(header.group(1))
            continue
        pair = KEY_VALUE.match(stripped)
        if current is None or not pair:
            continue
        key, value = pair.groups()
        if value.startswith('[') and not value.rstrip().endswith(']'):
            parts = [value]
            for continued in lines:
                kept = continued.strip()
                if kept and not kept.startswith('#'):
                    parts.append(kept)
                if kept.startswith(']'):
                    break
            value = ' '.join(parts)
        if value.startswith(('"', '[')):
            current[key] = ast.literal_eval(value)
    return tables


def colcon_metadata() -> dict[str, Any]:
    """setup()'s keywords from pyproject.toml, for setuptools that cannot read it."""
    tables = read_project_tables((HERE / 'pyproject.toml').read_text(encoding='utf-8'))
    project = tables['project']
    scripts = [f'{name} = {target}' for name, target in tables['project.scripts'].items()]
    return {
        'name': project['name'],
        'version': project['version'],
        'description': project['description'],
        'license': project['license'],
        'python_requires': project['requires-python'],
        'install_requires': project['dependencies'],
        'package_dir': {'': 'src'},
        'packages': find_packages(str(HERE / 'src')),
        'package_data': {PACKAGE: ['py.typed']},
        'entry_points': {'console_scripts': [*scripts, NODE_EXECUTABLE]},
        'zip_safe': False,
    }


def ros_data_files() -> list[tuple[str, list[str]]]:
    # The parameter files and the Fast DDS profile (examples/fastdds_announce.xml).
    configs = sorted(
        p.relative_to(HERE).as_posix()
        for pattern in ('*.yaml', '*.xml')
        for p in (HERE / 'examples').glob(pattern)
    )
    return [
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/launch', [f'launch/{PACKAGE}.launch.py']),
        (f'share/{PACKAGE}/config', configs),
    ]


class ColconDistribution(Distribution):
    """setup.py's metadata and setup.cfg only: pyproject.toml is left to pip."""

    def parse_config_files(self, filenames: Any = None, *args: Any, **kwargs: Any) -> None:
        # Naming the files keeps setuptools >= 61 from reading pyproject.toml's [project]
        # (which setuptools < 77 refuses); setup.cfg's install directories still apply.
        if filenames is None:
            filenames = self.find_config_files()
        super().parse_config_files(filenames, *args, **kwargs)


# tests/test_package.py imports this file under that name to check the reader above without
# building anything (distutils' run_setup, which colcon uses, does not run it as __main__).
if __name__ != 'scanfuse_setup_under_test':
    if os.environ.get('COLCON'):
        setup(distclass=ColconDistribution, data_files=ros_data_files(), **colcon_metadata())
    else:
        setup()
