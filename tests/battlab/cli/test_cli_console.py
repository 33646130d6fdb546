"""Rich output of the commands when stdout is not a terminal (a pipe, a file): tables at their full width."""

from __future__ import annotations

import click
from click.testing import CliRunner
from rich.table import Table

from battlab.cli.console import make_console


@click.command()
def _wide() -> None:
    t = Table(title="twelve wide columns")
    for k in range(12):
        t.add_column(f"column header number {k}")
    t.add_row(*(f"value-{k}-abcdefghijklmnop" for k in range(12)))
    make_console().print(t)
    make_console().print("a plain line")


def test_a_wide_table_is_whole_when_piped() -> None:
    r = CliRunner().invoke(_wide, [])
    assert r.exit_code == 0 and "…" not in r.stdout
    for k in range(12):
        assert f"column header number {k}" in r.stdout and f"value-{k}-abcdefghijklmnop" in r.stdout
    lines = r.stdout.splitlines()
    assert lines[-1] == "a plain line"  # nothing padded to the console's width
    assert max(len(line) for line in lines) < 400
