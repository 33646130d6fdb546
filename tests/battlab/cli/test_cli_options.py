"""Options spelled the same in every command: ``--physics dfn|standin`` (``auto`` where a default is picked); each
numeric option's one range check and message; ``--help`` texts; suggestions for mistyped cells and causes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from battlab.cli import main
from battlab.cli.options import DATA_FORMATS, DT, SOC, TEMPERATURE, Bounds
from battlab.cli.run import run
from battlab.cli.virtual_tester import serve
from protocols.errors import InputError

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


# -- ranges: one check and one message per option, whichever command takes it -------------------------------------
SOC0_MSG = "--soc0 {v}: the start SOC must be in [0, 1]"
DT_MSG = "--dt {v}: the time step must be > 0 s"
AMBIENT_MSG = "--ambient {v}: the temperature must be in [-40, 80] degC"
#: every command with the option, with its other arguments (files need not exist: the option is checked first)
TAKES = {
    "--soc0": [
        ["simulate", "nca18650", "p.csv", "-o", "o.csv"],
        ["fit", "d.csv", "--cell", "nca18650", "-o", "c.json"],
        ["validate", "d.csv", "--cell", "nca18650"],
        ["diagnose", "d.csv", "--cell", "nca18650", "-o", "r"],
        ["run", *RUN_ARGS],
        ["virtual-tester", "serve", *SERVE_ARGS],
        ["library", "list"],
    ],
    "--dt": [
        ["fit", "d.csv", "--cell", "nca18650", "-o", "c.json"],
        ["validate", "d.csv", "--cell", "nca18650"],
        ["diagnose", "d.csv", "--cell", "nca18650", "-o", "r"],
    ],
    "--ambient": [
        ["simulate", "nca18650", "p.csv", "-o", "o.csv"],
        ["sensitivity", "lib.h5", "--cell", "nca18650", "-o", "s.h5"],
        ["virtual-tester", "serve", *SERVE_ARGS],
        ["fit", "d.csv", "--cell", "nca18650", "-o", "c.json"],
        ["validate", "d.csv", "--cell", "nca18650"],
        ["diagnose", "d.csv", "--cell", "nca18650", "-o", "r"],
    ],
}
BAD = {"--soc0": [("-0.2", SOC0_MSG), ("1.5", SOC0_MSG), ("nan", SOC0_MSG)], "--dt": [("0", DT_MSG), ("-1", DT_MSG)]}
BAD["--ambient"] = [("200", AMBIENT_MSG), ("-273.15", AMBIENT_MSG)]


@pytest.mark.parametrize(
    ("args", "option", "value", "message"),
    [
        pytest.param(args, option, value, message.format(v=value), id=f"{args[0]} {option} {value}")
        for option, commands in TAKES.items()
        for args in commands
        for value, message in BAD[option]
    ],
)
def test_a_value_out_of_range_is_one_line_and_the_same_in_every_command(
    args: list[str], option: str, value: str, message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, [*args, option, value])
    assert r.exit_code == 2 and r.output == f"error: {message}\n", r.output
    assert list(tmp_path.iterdir()) == []  # refused before any work


def test_the_range_is_in_the_help_and_a_good_value_passes(tmp_path: Path) -> None:
    for args in TAKES["--soc0"]:
        text = CliRunner().invoke(main, [*args[: 2 if args[0] in ("virtual-tester", "library") else 1], "--help"])
        assert "in [0, 1]" in " ".join(text.output.split()), args
    with run.make_context("run", [*RUN_ARGS, "--soc0", "0.25"]) as ctx:
        assert ctx.params["soc0"] == 0.25
    with serve.make_context("serve", ["--soc0", "1", "--ambient", "-40"]) as ctx:
        assert ctx.params["soc0"] == 1.0 and ctx.params["ambient"] == -40.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--ambient", "a.mat=81"], "--ambient a.mat=81: the temperature must be in [-40, 80] degC"),
        (["--ambient", "a.mat=warm"], "--ambient 'a.mat=warm': expected DEGC or FILE=DEGC"),
        (["--ambient", "25", "--ambient", "10"], "--ambient '10': all files given twice"),
        (["--max-iter", "0"], "--max-iter 0: the number of evaluations must be >= 1"),
    ],
)
def test_the_ambient_per_file_and_the_evaluations_of_the_data_commands(args: list[str], message: str) -> None:
    for command in (["fit", "d.csv", "--cell", "c", "-o", "c.json"], ["diagnose", "d.csv", "--cell", "c", "-o", "r"]):
        r = CliRunner().invoke(main, [*command, *args])
        assert r.exit_code == 2 and r.output.startswith(f"error: {message}"), r.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--v-limits", "4.2,2.5"], "--v-limits 4.2,2.5: MIN (4.2 V) must be below MAX (2.5 V)"),
        (["--v-limits", "-1,4"], "--v-limits -1,4: a cell voltage must be in [0, 10] V"),
        (["--v-limits", "4.5"], "--v-limits '4.5': expected MIN,MAX in volts"),
        (["--T0", "90"], "--T0 90: the temperature must be in [-40, 80] degC"),
    ],
)
def test_voltage_limits_are_ordered_and_the_start_temperature_physical(args: list[str], message: str) -> None:
    r = CliRunner().invoke(main, ["simulate", "nca18650", "p.csv", "-o", "o.csv", *args])
    assert r.exit_code == 2 and r.output.startswith(f"error: {message}"), r.output


def test_bounds_say_their_range() -> None:
    assert SOC.describe() == "in [0, 1]" and DT.describe() == "> 0 s" and TEMPERATURE.describe() == "in [-40, 80] degC"
    assert Bounds("x", high=1.0, open_high=True).describe() == "< 1" and Bounds("x").describe() == "a finite number"
    assert SOC.check("--soc0", 0.0) == 0.0 and SOC.check("--soc0", 1.0) == 1.0
    for value in (-1e-12, 1 + 1e-12, math.inf, math.nan):
        with pytest.raises(InputError, match=r"^--soc0 .*: the start SOC must be in \[0, 1\]$"):
            SOC.check("--soc0", value)


# -- --help ---------------------------------------------------------------------------------------------------------
def _commands(group: click.Group, path: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [path]
    for name, cmd in group.commands.items():
        out += _commands(cmd, (*path, name)) if isinstance(cmd, click.Group) else [(*path, name)]
    return out


def test_no_help_shows_a_doubled_percent_sign() -> None:
    paths = _commands(main)
    assert len(paths) > 15
    for path in paths:
        r = CliRunner().invoke(main, [*path, "--help"], terminal_width=200)
        assert r.exit_code == 0 and "%%" not in r.output, (path, r.output)


@pytest.mark.parametrize("command", ["fit", "validate", "diagnose"])
def test_the_data_commands_say_which_files_they_read(command: str) -> None:
    text = " ".join(CliRunner().invoke(main, [command, "--help"], terminal_width=200).output.split())
    assert DATA_FORMATS in text
    for fmt in (".h5", "Battery Data Format CSV", "'Test Time / s', 'Voltage / V', 'Current / A'", ".mat"):
        assert fmt in text
    if command == "fit":
        assert "examples/panasonic/fit.sh" in text


# -- did you mean ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "nca18560", "p.csv", "-o", "o.csv"], "cell 'nca18560' (did you mean 'nca18650'?)"),
        (
            ["diagnose", "d.csv", "--cell", "nca18650-ture", "-o", "r"],
            "cell 'nca18650-ture' (did you mean 'nca18650-true'?)",
        ),
        (
            ["diagnose", "d.csv", "--cell", "nca18650", "--cause", "themal", "-o", "r"],
            "unknown model extension 'themal' (did you mean 'thermal'?)",
        ),
        (
            ["simulate", "nca18650", "p.csv", "--extension", "contact_resistence", "-o", "o.csv"],
            "unknown model extension 'contact_resistence' (did you mean 'contact_resistance'?)",
        ),
    ],
)
def test_a_mistyped_cell_or_cause_gets_a_suggestion(
    args: list[str], message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and message in r.output and len(r.output.splitlines()) == 1, r.output


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_bad_preparation_is_one_line_before_anything_is_simulated(
    tmp_path: Path, prepared_measurement, command: str
) -> None:
    prep, meas = prepared_measurement(tmp_path)
    args = [command, str(meas), "--cell", "nca18650", "-o", str(tmp_path / "out.json")]
    for bad, says in (
        (f"{meas}", "expected DATA=PREP"),
        (f"{meas}={tmp_path / 'nope.h5'}", "nope.h5: no such file"),
        (f"{tmp_path / 'other.h5'}={prep}", "is not one of the data files"),
    ):
        r = CliRunner().invoke(main, [*args, "--preparation", bad])
        assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, r.output
        assert len(r.output.strip().splitlines()) == 1, r.output
