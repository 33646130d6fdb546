"""``battlab fit`` and ``battlab validate``: thin shells over :mod:`battlab.identify.workflow` (identify a cell
from logged data, score cells on held-out data).

DATA: our HDF5 run logs (``.h5``), BDF CSV (``.csv``, optional ``.summary.json`` sidecar) or Panasonic ``.mat``.
A slow test (|I| ≤ C/10 for at least 5 h) is taken as the OCV test for the equilibrium fit; the others are
dynamic data. A run log is cut at the profile steps of the plan it ran (kept in its metadata; ``--plan`` must be
that plan): one experiment per profile, named ``<log>:<profile id>``, and the design's groups (from ``--plan``'s
summary, else those the runner kept in the log) are the stages.

Outputs: the BPX cell (intervals and fit report under "User-defined") and ``<cell>.summary.json`` next to it:
``{"parameters": {name: {"value", "ci95": [lo, hi], "at_bound"}}, "rmse_mV": {data: value}, "converged": bool, ...}``.
"""

from __future__ import annotations

from typing import Any

import click

from battlab.cli.fit_display import FitDisplay, print_estimates, verdict
from battlab.cli.options import (
    AMBIENT_OPTION,
    DATA_FORMATS,
    apply_extensions,
    apply_ocps,
    dataclass_options,
    dt_option,
    extension_option,
    ocp_option,
    parse_ambients,
    parse_preparations,
    preparation_option,
    soc0_option,
)
from battlab.identify.fit_options import cli_fields
from protocols.errors import InputError


@click.command(
    "fit",
    epilog=f"{DATA_FORMATS} A real cell from its lab's files: see examples/panasonic/fit.sh (the recipe for the "
    "Panasonic NCR18650PF at 25, 10 and 0 degC).",
)
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cell_name", required=True, help="Start cell: a built-in name or a BPX file.")
@dataclass_options(cli_fields())
@AMBIENT_OPTION
@extension_option()
@ocp_option()
@click.option(
    "--fit-values",
    "value_stages",
    multiple=True,
    metavar="[TARGET:]NAMES",
    help="After the stages, fit cell values outside the 18 (e.g. R_c, E_kappa, h2a; C1+C2: one factor on both) to "
    "the voltage (default) or the surface 'temperature:' by finite differences; repeat for several fits, in order.",
)
@preparation_option()
@click.option(
    "--noise",
    "noise_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="Noise model (eq. 38) that weighs the residuals: noise.toml, or a campaign's noise/noise.json [default: "
    "fitted to the repeated trials in the run logs, else the paper's coefficients].",
)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="cell.bpx.json")
def fit(
    data: tuple[str, ...],
    cell_name: str,
    ambients: tuple[str, ...],
    extensions: tuple[str, ...],
    ocps: tuple[str, ...],
    value_stages: tuple[str, ...],
    preparations: tuple[str, ...],
    noise_file: str | None,
    output: str,
    **settings: Any,
) -> None:
    """Identify CELL's parameters from DATA (equilibrium from an OCV test, dynamics by weighted LM).

    DATA: run logs (.h5), BDF CSV (.csv, .bdf.csv) or Panasonic .mat files; a slow test (|I| <= C/10 for at least
    5 h) is the OCV test.

    The result is written after the equilibrium fit and after every stage, marked partial until the last; a failing
    stage is one line naming it and exit code 1, with the finished stages (or the equilibrium fit) kept.

    The residuals are weighted by a noise model (eqs. 36-40): --noise FILE, else eq. 38 fitted to the repeated
    trials in the run logs (a plan's noise trials, `battlab design --noise-trials`), else the paper's coefficients;
    the output and the summary's "noise" say which."""
    import sys

    from battlab.identify import values, workflow
    from battlab.io import paths

    if noise_file is not None:  # a bad file is one line before any data is read
        from battlab.noise import load

        load(noise_file)
    start: Any = cell_name
    if extensions or ocps:  # the extensions' parameters join the last stage (with --params all: every parameter)
        from battlab.cell import Cell

        start = apply_extensions(apply_ocps(Cell.load(cell_name), ocps), extensions)
    out = paths.check_output_path(output, create=True)
    stem = out.name.removesuffix(".json").removesuffix(".bpx")
    summary_path = paths.summary_path(out)
    plan = settings.get("plan")
    if plan is not None and paths.summary_path(plan).resolve() == summary_path.resolve():
        click.echo(
            f"warning: {summary_path} (the design's summary) is replaced by the fit's summary; give the fitted "
            "cell another name than the plan to keep both",
            err=True,
        )
    settings["per_file_ageing"] = settings.get("per_file_ageing") or ()
    options = workflow.FitOptions(
        data=data,
        cell=start,
        ambient=parse_ambients(ambients),
        value_stages=tuple(values.parse_value_stage(v) for v in value_stages),
        preparations=parse_preparations(preparations),
        noise=noise_file,
        output=out,
        **settings,
    )
    display = FitDisplay(out, stem)
    try:
        rep = workflow.fit(options, [display])
    except workflow.StageFailed as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2 if isinstance(exc.cause, InputError) else 1)
    except KeyboardInterrupt:
        _interrupted(display, out, summary_path)
    if "noise" in rep.summary:
        _print_noise(rep.summary["noise"])
    last = rep.last
    if last is not None:
        print_estimates(last, rep.summary)
        if not last.statistics.valid:
            click.echo(f"warning: {last.statistics.reason}", err=True)
    if "per_file_ageing" in rep.summary:
        _print_ageing(rep.summary["per_file_ageing"])
    if last is not None:
        click.echo(verdict(rep.summary))
    click.echo(f"wrote {out}, {summary_path} and {out.with_name('summary.json')}")


def _interrupted(display: FitDisplay, out: Any, summary_path: Any) -> None:
    """Ctrl-C: say what was kept on disk, exit 130."""
    import json
    import sys

    done = display.done
    written = done or display.equilibrium_written
    status = json.loads(summary_path.read_text()).get("status", "") if written else ""
    if status.startswith("complete"):  # while the last stage's figures were drawn
        click.echo(f"interrupted after the fit; {status.removeprefix('complete: ')} written to {out}", err=True)
    elif written:
        kept = status.removeprefix("partial: ") or "the finished stages"
        click.echo(f"interrupted in stage {done + 1}; {kept} kept (partial) in {out} and {summary_path}", err=True)
    else:
        click.echo(f"interrupted in stage 1; no stage finished, nothing written to {out}", err=True)
    sys.exit(130)


def _print_noise(info: dict[str, Any]) -> None:
    """Which noise model weighed the residuals, and the repeated trials' noise levels."""
    m = info["model"]
    click.echo(
        f"noise model: {info['source']}: charge q = {m['a_c']:.4g} I + {m['b_c']:.4g} V, discharge q = "
        f"{m['a_d']:.4g} exp({m['b_d']:.4g} I) V, floor {m['floor']:.3g} V (I: input intensity, A s^0.5)"
    )
    for t in info.get("trials", []):
        click.echo(
            f"  repeated trials of profile {t['profile']} ({t['direction']}, intensity {t['intensity']:.1f} A s^0.5): "
            f"{t['trials']} trials, q {1e6 * t['q_V']:.0f} uV"
        )


def _print_ageing(block: dict[str, Any]) -> None:
    """Each file's ageing values with their 95 % intervals, and the state the written cell holds."""
    for f, vals in block["files"].items():
        parts = []
        for n, v in vals.items():
            ci = f" [{v['ci95'][0]:.5g}, {v['ci95'][1]:.5g}]" if v["ci95"] else ""
            parts.append(f"{n} {v['value']:.5g}{ci}" + (f" (at {v['at_bound']} bound)" if v["at_bound"] else ""))
        click.echo(f"ageing of {f}: " + ", ".join(parts))
    ex = block["exported"]
    click.echo(
        "written cell: the mean, "
        + ", ".join(f"{n} {ex[n]:.5g}" for n in block["names"])
        + f" (start cell's n_Li {ex['reference_n_Li']:.5g} mol)"
    )


@click.command("validate", epilog=DATA_FORMATS)
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cells", multiple=True, required=True, help="A cell to score (repeat for several).")
@soc0_option()
@AMBIENT_OPTION
@dt_option()
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@click.option(
    "-o",
    "--output",
    default="validation",
    show_default=True,
    type=click.Path(file_okay=False),
    help="Directory for the figures and the summary (<DIR>/<DIR>.summary.json).",
)
def validate(
    data: tuple[str, ...],
    cells: tuple[str, ...],
    soc0: float | None,
    ambients: tuple[str, ...],
    dt: float,
    fix_sign: bool,
    output: str,
) -> None:
    """Print the voltage RMSE of each CELL on each DATA file and save the figures (Figs. 7 and 9)."""
    from battlab.identify.validate import validate
    from battlab.identify.validation import format_table
    from battlab.io.paths import check_output_path

    check_output_path(output, directory=True, create=True)
    rep = validate(data, cells, soc0=soc0, ambient=parse_ambients(ambients), dt=dt, fix_sign=fix_sign)
    for w in rep.warnings:
        click.echo(f"warning: {w}", err=True)
    click.echo(format_table(rep.table, rep.coverage))
    summary = rep.write(output)
    click.echo(f"figures in {output}, summary {summary}")
