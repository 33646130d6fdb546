"""Options spelled the same in every command: ``--physics dfn|standin`` (``auto`` where a default is picked)."""

from __future__ import annotations

import json

import click
import pytest
from click.testing import CliRunner

from battlab.cli import main
from battlab.cli.run import run
from battlab.cli.virtual_tester import serve

COMMANDS = {"run": run, "virtual-tester serve": serve}
RUN_ARGS = ["plan.toml", "--cycler", "virtual", "--chamber", "virtual", "-o", "r.h5"]
SERVE_ARGS = ["--cycler-port", "0", "--chamber-port", "0", "--espec-port", "0", "--duration", "0", "--json"]


def _physics(command: click.Command, *physics: str) -> str:
    """The value ``--physics`` parses to (nothing run)."""
    args = RUN_ARGS if command is run else []
    extra = ["--physics", *physics] if physics else []
    with command.make_context(command.name or "", [*args, *extra]) as ctx:
        return ctx.params["physics"]


@pytest.mark.parametrize("name", list(COMMANDS))
def test_physics_takes_the_same_choices_in_every_command(name: str) -> None:
    command = COMMANDS[name]
    choices = next(p for p in command.params if p.name == "physics").type.choices  # type: ignore[attr-defined]
    assert {"dfn", "standin"} <= set(choices)
    for spelling, value in (("dfn", "dfn"), ("standin", "standin"), ("stand-in", "standin"), ("STANDIN", "standin")):
        assert _physics(command, spelling) == value
    assert _physics(command, "auto") in ("auto", "dfn")  # serve picks by what is installed; run has the model
    r = CliRunner().invoke(main, [*name.split(), "--physics", "nonsense", *(RUN_ARGS if command is run else [])])
    assert r.exit_code == 2 and "'dfn'" in r.stderr and "'standin'" in r.stderr, r.stderr
    text = CliRunner().invoke(main, [*name.split(), "--help"]).output
    assert "dfn" in text and "standin" in text


def test_defaults_are_unchanged() -> None:
    assert _physics(run) == "dfn" and _physics(serve) == "auto"


def test_serve_with_dfn_physics_serves_battlab_s_model() -> None:
    r = CliRunner().invoke(main, ["virtual-tester", "serve", *SERVE_ARGS, "--physics", "dfn"])
    assert r.exit_code == 0, (r.output, r.exception)
    assert json.loads(r.stdout.splitlines()[0])["physics"] == "battlab.lab.virtual.make_cell_physics('nca18650')"
