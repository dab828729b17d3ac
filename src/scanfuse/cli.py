"""`scanfuse` command line: thin typer commands over the API functions.

Known errors (ScanfuseError) become one clean red line and exit code 1; anything
else keeps its traceback.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from scanfuse.errors import ScanfuseError

app = typer.Typer(
    name='scanfuse',
    help='Depth camera + 2D LiDAR fusion for ROS 2.',
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help='folder for the report, figures and bag')] = Path(
        'results/demo'
    ),
) -> None:
    """Run scanfuse on the embedded default and write a report with figures."""
    from scanfuse.demo import run_demo  # noqa: PLC0415

    run_demo(out, console=Console())


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `scanfuse` command; returns the exit code."""
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    try:
        app(args=argv, standalone_mode=False)
    except ScanfuseError as err:
        console.print(f'[bold red]error:[/] {err}')
        return 1
    except typer.Exit as err:
        return int(err.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        console.print('[red]aborted[/]')
        return 130
    except Exception as err:  # click usage errors carry their own exit code
        import click  # noqa: PLC0415

        if isinstance(err, click.ClickException):
            err.show()
            return err.exit_code
        raise
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
