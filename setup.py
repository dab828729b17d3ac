"""colcon's way into the package; pip builds from pyproject.toml and gets nothing from here.

colcon (the ament_python build type) runs `setup.py`. In its subprocesses the variable
COLCON is set (colcon-core sets it for exactly that), and only then does this add what a
ROS 2 package installs beside its Python code: the ament index marker, package.xml, the
launch file and the parameter files under share/scanfuse, and the `scanfuse_node`
executable (setup.cfg sends executables to lib/scanfuse, where `ros2 run` looks).
`colcon build` and `colcon build --symlink-install` both work (tests/test_package.py).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from setuptools import setup
from setuptools.config.pyprojecttoml import apply_configuration
from setuptools.dist import Distribution

PACKAGE = 'scanfuse'
NODE_EXECUTABLE = 'scanfuse_node = scanfuse.__main__:node_entry'


def ros_data_files() -> list[tuple[str, list[str]]]:
    here = Path(__file__).resolve().parent
    # The parameter files and the Fast DDS profile (examples/fastdds_announce.xml).
    configs = sorted(
        p.relative_to(here).as_posix()
        for pattern in ('*.yaml', '*.xml')
        for p in (here / 'examples').glob(pattern)
    )
    return [
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/launch', [f'launch/{PACKAGE}.launch.py']),
        (f'share/{PACKAGE}/config', configs),
    ]


class ColconDistribution(Distribution):
    """pyproject.toml's metadata plus the ROS executable, in a form colcon can read back."""

    def parse_config_files(self, *args: Any, **kwargs: Any) -> None:
        super().parse_config_files(*args, **kwargs)
        if not Path('pyproject.toml').is_file():
            # `colcon build --symlink-install` runs setup.py (a symlink) in the build folder,
            # where colcon links the packages and data files but not pyproject.toml.
            apply_configuration(self, Path(__file__).resolve().parent / 'pyproject.toml')
        # pyproject.toml's [project.scripts] replaces any entry_points given to setup().
        self.entry_points = dict(self.entry_points or {})
        scripts = self.entry_points.setdefault('console_scripts', [])
        if NODE_EXECUTABLE not in scripts:
            scripts.append(NODE_EXECUTABLE)
        # requires-python arrives as packaging's SpecifierSet, whose repr is no Python
        # literal: colcon-python-setup-py (0.2.9) reads the options with ast.literal_eval.
        for holder in (self, self.metadata):
            value = getattr(holder, 'python_requires', None)
            if value is not None:
                holder.python_requires = str(value)


if os.environ.get('COLCON'):
    setup(distclass=ColconDistribution, data_files=ros_data_files())
else:
    setup()
