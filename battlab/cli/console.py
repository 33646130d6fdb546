"""The rich console of the commands: the terminal's width on a terminal, the tables' full width otherwise."""

from __future__ import annotations

from rich.console import Console

#: width when the output is not a terminal (a pipe, a file, a test runner): wide enough that no table is cut
#: and no line is wrapped; rich draws a table at its natural width, so nothing is padded to this
PIPE_WIDTH = 100_000


def make_console(*, stderr: bool = False) -> Console:
    """A console on stdout (or stderr); when that is not a terminal, tables are printed at their full width
    instead of rich's default 80 columns, which cuts columns to '…'."""
    console = Console(stderr=stderr)
    if console.is_terminal:
        return console
    return Console(stderr=stderr, width=PIPE_WIDTH)


__all__ = ["make_console"]
