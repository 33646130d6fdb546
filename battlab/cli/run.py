"""``battlab run PLAN`` and ``battlab runs list | show | resume``: the experiment runner from the command line.

Exit codes: 0 completed, 1 aborted (the reason on stderr), 130 stopped by Ctrl-C, 2 a user error (bad plan,
limits, URL, an instrument that cannot be reached, does not answer or lacks what was asked of it before the run
starts: one line, and nothing catalogued or logged).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import sys
from pathlib import Path
from typing import Any

import click

from battlab.cli.options import physics_option, soc0_option
from protocols.errors import InputError


def _finish(result: Any) -> None:
    from battlab.lab.progress import describe

    rows = result.summary.get("stats", {}).get("samples", 0)
    line = f"run {result.run_id} {result.status}: {result.log_path} ({rows:,} samples this session)"
    if result.status == "completed":
        click.echo(line)
        click.echo("  " + describe(result.summary))
        return
    click.echo(f"{line}\n  reason: {result.reason}", err=True)
    click.echo(f"  resume with: battlab runs resume {result.run_id}", err=True)
    sys.exit(130 if result.status == "stopped" else 1)


def _logging(verbose: bool) -> None:
    """WARNING and up, one line each; ``--verbose``: INFO (state changes, every failed exchange and retry). pymodbus
    logs each failed connection and frame itself: silenced unless verbose (the runner reports what failed)."""
    fmt = "%(levelname)s %(name)s: %(message)s"
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format=fmt)
    for name in ("pymodbus", "pymodbus.logging"):
        logging.getLogger(name).setLevel(logging.NOTSET if verbose else logging.CRITICAL)


@click.command("run")
@click.argument("plan", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--cycler",
    "cycler_url",
    required=True,
    help="Cycler URL, e.g. socket://HOST:PORT, /dev/ttyUSB0 or virtual (an unknown scheme lists the registered ones).",
)
@click.option(
    "--chamber",
    "chamber_url",
    required=True,
    help="Chamber URL, e.g. modbus-tcp://HOST:PORT, espec://HOST:PORT or virtual.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="The run log (HDF5, a new file).",
)
@click.option("--cell", default="nca18650", show_default=True, help="Cell: a built-in name or a BPX/TOML file.")
@click.option(
    "--limits",
    "limits_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Instrument limits TOML (required for real instruments).",
)
@click.option(
    "--dialect", default=None, help="SCPI dialect of the cycler (default: the limits file's, else battlab-virtual)."
)
@click.option(
    "--speed",
    type=click.FloatRange(min=1e-3, max=1e6),
    default=None,
    help="Speed of the in-process virtual tester (virtual URLs only; default 1000).",
)
@soc0_option("Start SOC: of the virtual cell (virtual URLs), else recorded as the known start state")
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed of the in-process virtual tester.")
@physics_option(auto=False, default="dfn")
@click.option(
    "--library",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Profile library for library_id steps (default: the plan's, else the built-in one).",
)
@click.option("--quiet", is_flag=True, help="No progress display (the result lines are always printed).")
@click.option("-v", "--verbose", is_flag=True, help="Log state changes and retries.")
def run(
    plan: Path,
    cycler_url: str,
    chamber_url: str,
    output: Path,
    cell: str,
    limits_path: Path | None,
    dialect: str | None,
    speed: float | None,
    soc0: float | None,
    seed: int,
    physics: str,
    library: Path | None,
    quiet: bool,
    verbose: bool,
) -> None:
    """Run PLAN (a protocol TOML/JSON with an optional [run] table) on a cycler and a chamber, logging to -o."""
    from battlab.io.paths import check_output_path
    from battlab.lab.session import VIRTUAL, RunSettings, start_run

    check_output_path(output)
    _logging(verbose)
    is_virtual = VIRTUAL in (cycler_url.strip(), chamber_url.strip())
    if speed is not None and not is_virtual:
        raise InputError("--speed applies to the in-process virtual tester only (--cycler/--chamber virtual)")
    settings = RunSettings(
        cycler_url=cycler_url,
        chamber_url=chamber_url,
        cell=cell,
        limits_path=str(limits_path.resolve()) if limits_path else None,
        dialect=dialect,
        speed=speed if speed is not None else 1000.0,
        soc0=soc0,
        seed=seed,
        physics=physics,
        library=str(library.resolve()) if library else None,
    )
    _finish(start_run(plan, settings, output, display=not quiet))


@click.group("runs")
def runs() -> None:
    """The run catalog ($BATTLAB_HOME/runs.sqlite or ~/.local/share/battlab/runs.sqlite)."""


@runs.command("list")
@click.option("-n", "limit", type=click.IntRange(min=1), default=None, help="Only the N newest runs.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per run.")
def list_runs(limit: int | None, as_json: bool) -> None:
    """Runs, newest first: id, status (running, completed, aborted, stopped, interrupted), steps, log, reason."""
    from battlab.lab.catalog import Catalog

    records = Catalog().list(limit)
    if as_json:
        for r in records:
            click.echo(
                json.dumps(
                    {
                        "id": r.id,
                        "status": r.shown_status,
                        "reason": r.reason,
                        "name": r.name,
                        "log": r.log_path,
                        "next_entry": r.next_entry,
                        "n_entries": r.n_entries,
                        "rows": r.rows,
                        "resumes": r.resumes,
                        "created": r.created,
                    }
                )
            )
        return
    if not records:
        click.echo("no runs yet")
        return
    click.echo(f"{'id':>4}  {'status':<11} {'started':<16} {'steps':>9}  {'name':<24} log / reason")
    for r in records:
        started = _dt.datetime.fromtimestamp(r.created).strftime("%Y-%m-%d %H:%M")
        steps = f"{r.next_entry}/{r.n_entries}"
        click.echo(f"{r.id:>4}  {r.shown_status:<11} {started:<16} {steps:>9}  {r.name[:24]:<24} {r.log_path}")
        if r.reason:
            click.echo(f"{'':>4}  {'':<11} {'':<16} {'':>9}  {'':<24} {r.reason}")


@runs.command("show")
@click.argument("run_id", type=int)
def show_run(run_id: int) -> None:
    """One run's record and its steps, as JSON."""
    from battlab.lab.catalog import Catalog

    cat = Catalog()
    r = cat.get(run_id)
    out = {
        "id": r.id,
        "status": r.shown_status,
        "reason": r.reason,
        "name": r.name,
        "plan_path": r.plan_path,
        "log": r.log_path,
        "settings": r.settings,
        "next_entry": r.next_entry,
        "n_entries": r.n_entries,
        "resumes": r.resumes,
        "steps": cat.steps(run_id),
    }
    click.echo(json.dumps(out, indent=1))


@runs.command("resume")
@click.argument("run_id", type=int)
@click.option("--cycler", "cycler_url", default=None, help="Override the cycler URL recorded for the run.")
@click.option("--chamber", "chamber_url", default=None, help="Override the chamber URL recorded for the run.")
@click.option("--quiet", is_flag=True, help="No progress display (the result lines are always printed).")
@click.option("-v", "--verbose", is_flag=True, help="Log state changes and retries.")
def resume(run_id: int, cycler_url: str | None, chamber_url: str | None, quiet: bool, verbose: bool) -> None:
    """Resume run RUN_ID from its first step not completed (that step restarts from its beginning)."""
    from battlab.lab.session import resume_run

    _logging(verbose)
    overrides = {k: v for k, v in (("cycler_url", cycler_url), ("chamber_url", chamber_url)) if v}
    _finish(resume_run(run_id, overrides=overrides, display=not quiet))


__all__ = ["run", "runs"]
