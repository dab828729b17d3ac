"""Progress of long work (a bag, a simulation, an evaluation): one protocol, two reporters.

Library code reports to a `Progress` and never branches on whether anyone watches:
`NullProgress` is the do-nothing stand-in, `RichProgress` the bar the CLI shows.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.progress import Progress as RichBar

if TYPE_CHECKING:
    from rich.console import Console


class Progress(Protocol):
    """Where long work says how far it got."""

    def start(self, description: str, total: float) -> None: ...

    def advance(self, amount: float = 1.0) -> None: ...

    def finish(self) -> None: ...


class NullProgress:
    """Reports nowhere."""

    def start(self, description: str, total: float) -> None:
        pass

    def advance(self, amount: float = 1.0) -> None:
        pass

    def finish(self) -> None:
        pass


class RichProgress:
    """A rich progress bar: description, bar, done/total, elapsed and remaining time."""

    def __init__(
        self, console: Console | None = None, *, unit: str = '', transient: bool = False
    ) -> None:
        columns = [
            TextColumn('[progress.description]{task.description}'),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(unit),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
        ]
        self._bar = RichBar(*columns, console=console, transient=transient)
        self._task = TaskID(0)

    def start(self, description: str, total: float) -> None:
        self._bar.start()
        self._task = self._bar.add_task(description, total=total)

    def advance(self, amount: float = 1.0) -> None:
        self._bar.advance(self._task, amount)

    def finish(self) -> None:
        self._bar.stop()
