"""Tables that print as text: `print(report.table())` shows the table, not an object."""

from __future__ import annotations

import io

from rich.console import Console
from rich.table import Table

WIDTH = 80  # a terminal's columns: tables wrap their cells to fit


class TextTable(Table):
    """A rich Table whose str() (and so print()) is its text, at most WIDTH columns wide."""

    def __str__(self) -> str:
        buffer = io.StringIO()
        Console(file=buffer, width=WIDTH, color_system=None, soft_wrap=False).print(self)
        return buffer.getvalue()
