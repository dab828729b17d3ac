"""The documentation site builds without a warning, the README's links lead into it, and
every default the pages quote is the parameter table's."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import pytest
import yaml

from scanfuse.config import FusionConfig
from scanfuse.ros.params import NodeSettings, all_param_specs
from tests.support import REPOSITORY

PAGES = [REPOSITORY / 'README.md', *sorted((REPOSITORY / 'docs').glob('*.md'))]
# `name` (default VALUE)   and   `name: VALUE` (the default)
QUOTED = (
    re.compile(r'`(\w+)` \(default:? ([^),;]+)[),;]'),
    re.compile(r'`(\w+): ([^`]+)` \(the default\)'),
)


def test_mkdocs_builds_the_site_strictly(tmp_path):
    done = subprocess.run(
        [sys.executable, '-m', 'mkdocs', 'build', '--strict', '--site-dir', str(tmp_path)],
        cwd=REPOSITORY,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / 'index.html').is_file()
    assert (tmp_path / 'parameters' / 'index.html').is_file()


def test_the_readme_links_to_pages_that_exist():
    text = (REPOSITORY / 'README.md').read_text(encoding='utf-8')
    targets = re.findall(r'\]\((docs/[^)#]+)', text)
    assert targets
    missing = [target for target in targets if not (REPOSITORY / target).is_file()]
    assert missing == []


def test_the_readme_starts_with_the_two_commands_and_stays_short():
    lines = (REPOSITORY / 'README.md').read_text(encoding='utf-8').splitlines()
    assert len(lines) <= 200
    first_block = lines[lines.index('```sh') + 1 : lines.index('```')]
    assert [line.split('#')[0].strip() for line in first_block] == ['make demo', 'make test']


def defaults() -> dict[str, object]:
    return {spec.name: spec.default for spec in all_param_specs(FusionConfig(), NodeSettings())}


def scalar(value: str) -> object:
    """The number or boolean a quoted default starts with, else None ("the global one")."""
    words = value.split()
    parsed = yaml.safe_load(words[0]) if words else None
    return parsed if isinstance(parsed, int | float | bool) else None


def quoted_defaults() -> list[tuple[str, str, str]]:
    """(page, name, quoted value) of every number or boolean a page quotes as a parameter's
    default."""
    known = defaults()
    found = []
    for page in PAGES:
        text = ' '.join(page.read_text(encoding='utf-8').split())
        for pattern in QUOTED:
            for name, value in pattern.findall(text):
                if name in known and scalar(value) is not None:
                    found.append((page.name, name, value.strip()))
    return found


def test_the_pages_quote_defaults():
    # If the patterns stopped matching, the test below would check nothing.
    assert len(quoted_defaults()) >= 3


@pytest.mark.parametrize(('page', 'name', 'value'), quoted_defaults())
def test_a_quoted_default_is_the_parameter_tables(page, name, value):
    default = defaults()[name]
    quoted = scalar(value)
    if isinstance(default, float) and isinstance(quoted, int | float):
        assert math.isclose(quoted, default, abs_tol=1e-9), (page, name, value, default)
    else:
        assert quoted == default, (page, name, value, default)


# `--option` (default VALUE)   and   `--option`, default VALUE
QUOTED_OPTION = re.compile(r'`(--[\w-]+)`,? \(?default:? ([^),;]+)[),;]')
# Units the pages give option values in, to the options' own (seconds, hertz).
UNITS = {'': 1.0, 's': 1.0, 'ms': 1e-3, 'hz': 1.0}


def option_defaults() -> dict[str, list[object]]:
    """Every `scanfuse` command's options' defaults, by option name (typer's own record)."""
    import typer

    from scanfuse.cli import app

    found: dict[str, list[object]] = {}
    group = typer.main.get_command(app)
    for command in group.commands.values():  # type: ignore[attr-defined]
        for param in command.params:
            for name in param.opts:
                if name.startswith('--'):
                    found.setdefault(name, []).append(param.default)
    return found


def quoted_option_defaults() -> list[tuple[str, str, str]]:
    """(page, option, quoted value) of every default a page quotes for a command's option."""
    known = option_defaults()
    found = []
    for page in PAGES:
        text = ' '.join(page.read_text(encoding='utf-8').split())
        for name, value in QUOTED_OPTION.findall(text):
            if name in known:
                found.append((page.name, name, value.strip()))
    return found


def test_the_pages_quote_option_defaults():
    # If the pattern stopped matching, the test below would check nothing.
    assert len(quoted_option_defaults()) >= 2


def run_time_default(name: str) -> object:
    """What an option whose default is None takes at run time."""
    if name == '--depth-rate':  # the simulated camera's own rate
        from scanfuse.sim.sensors import camera_profile
        from scanfuse.sim.simulation import SimConfig

        return camera_profile(SimConfig().camera).rate
    raise AssertionError(f'{name}: a page quotes a default the code works out at run time')


@pytest.mark.parametrize(('page', 'name', 'value'), quoted_option_defaults())
def test_a_quoted_option_default_is_the_commands(page, name, value):
    defaults = [run_time_default(name) if d is None else d for d in option_defaults()[name]]
    number, _, unit = value.partition(' ')
    quoted = scalar(number)
    if isinstance(quoted, int | float) and not isinstance(quoted, bool):
        seconds = quoted * UNITS[unit.strip().lower()]
        assert any(math.isclose(seconds, float(d)) for d in defaults), (page, name, value)
    else:
        assert value.strip('`') in [str(d) for d in defaults], (page, name, value, defaults)


def test_the_readme_names_the_nodes_default_topics():
    text = ' '.join((REPOSITORY / 'README.md').read_text(encoding='utf-8').split())
    sentence = text[text.index('The node subscribes') : text.index('Every value comes from')]
    named = set(re.findall(r'`(/[\w/]+)`', sentence))
    known = defaults()
    topics = {
        str(known[name])
        for name in (
            'scan_topic',
            'depth_topic',
            'camera_info_topic',
            'odom_topic',
            'fused_topic',
            'instant_topic',
            'depth_scan_topic',
        )
    }
    # Every default input and output topic, and nothing else but ROS's own TF and diagnostics.
    assert topics <= named
    assert named - topics <= {'/tf', '/tf_static', '/diagnostics'}
