"""The `scanfuse` command's entry point (also `python -m scanfuse`).

SIGTERM ends the command with exit code 143 from its first instant: until a command takes
it over (`scanfuse.cli.terminate_as_interrupt`, which removes what it was writing), while
Python still imports the command line, numpy and the compiled kernels, it exits at once
(there is nothing to clean up yet). Without it a process stopped in its first second died
of the signal (-15) instead of exiting.
"""

from __future__ import annotations

import os
import signal
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from types import FrameType


def _exit_terminated(signum: int, _frame: FrameType | None) -> None:
    # Not SystemExit: raised inside a class's creation while a module imports, Python 3.11
    # wraps it in a RuntimeError (a traceback and exit code 1), and a finaliser drops it.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(128 + signum)


def main() -> int:
    """Run `scanfuse` with the arguments of this process; returns the exit code."""
    signal.signal(signal.SIGTERM, _exit_terminated)
    from scanfuse.cli import main as cli_main  # noqa: PLC0415 - after the handler, on purpose

    return cli_main()


def node_entry() -> int:
    """`ros2 run scanfuse scanfuse_node ARGS` (the colcon package's executable), the same way."""
    signal.signal(signal.SIGTERM, _exit_terminated)
    from scanfuse.cli import node_entry as cli_node_entry  # noqa: PLC0415 - as in `main`

    return cli_node_entry()


if __name__ == '__main__':
    sys.exit(main())
