"""``battlab diagnose``: a thin shell over :func:`battlab.diagnose.workflow.diagnose` (where the cell's simulation
disagrees with logged data, which model extension explains it, and whether it predicts held-out data).

Writes ``report/summary.json`` (``{"cause", "ranking": [{"cause", "score", ...}], "extension_gain":
{"rmse_before_mV", "rmse_after_mV", "held_out"}, ...}``), ``report/report.html`` with its PNG figures, and prints
a one-screen summary.
"""

from __future__ import annotations

import click

from battlab.cli.options import (
    AMBIENT_OPTION,
    DATA_FORMATS,
    dt_option,
    max_iter_option,
    parse_ambients,
    parse_preparations,
    preparation_option,
    soc0_option,
)


@click.command("diagnose", epilog=DATA_FORMATS)
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cell_name", required=True, help="The cell: a built-in name or a BPX file.")
@click.option(
    "--held-out",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="Data to hold out for the confirmation (repeat for several; default: the last file; with one file its "
    "final 30 %).",
)
@AMBIENT_OPTION
@soc0_option()
@dt_option()
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@preparation_option()
@click.option(
    "--full-charge-soc",
    type=click.FloatRange(0.5, 1.0),
    default=1.0,
    show_default=True,
    help="The SOC the preparations' full charge leaves (a fit with --preparation reports it: its summary's "
    "start_soc); the lead-ins start there.",
)
@click.option(
    "--cause", "causes", multiple=True, help="Test only this catalog cause (repeat; default: every testable one)."
)
@max_iter_option("Function evaluations per held-out fit", default=20)
@click.option(
    "--decide",
    is_flag=True,
    help="When the data cannot tell causes apart, design the experiment that separates them, run it on --cycler and "
    "--chamber, add its log and diagnose again (until one cause wins or --budget-hours are spent).",
)
@click.option("--cycler", "cycler_url", default="virtual", show_default=True, help="Cycler URL for --decide.")
@click.option("--chamber", "chamber_url", default="virtual", show_default=True, help="Chamber URL for --decide.")
@click.option("--truth", default=None, help="The virtual tester's hidden cell (--decide on 'virtual').")
@click.option(
    "--budget-hours", type=float, default=24.0, show_default=True, help="Lab hours the deciding experiments may take."
)
@click.option(
    "--ambients",
    "decide_ambients",
    default="10,25,40",
    show_default=True,
    metavar="DEGC,...",
    help="Ambient temperatures the chamber reaches [degC] for --decide (one: a bench without a chamber range).",
)
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Report directory.")
def diagnose(
    data: tuple[str, ...],
    cell_name: str,
    held_out: tuple[str, ...],
    ambients: tuple[str, ...],
    soc0: float | None,
    dt: float,
    fix_sign: bool,
    preparations: tuple[str, ...],
    full_charge_soc: float,
    causes: tuple[str, ...],
    max_iter: int,
    decide: bool,
    cycler_url: str,
    chamber_url: str,
    truth: str | None,
    budget_hours: float,
    decide_ambients: str,
    output: str,
) -> None:
    """Find which model extension explains where CELL disagrees with DATA, and check it on held-out data."""
    from battlab.diagnose import workflow
    from battlab.io.paths import check_output_path
    from battlab.progress import lines

    out = check_output_path(output, directory=True, create=True)
    options = workflow.DiagnoseOptions(
        data,
        cell_name,
        held_out=held_out,
        soc0=soc0,
        ambient=parse_ambients(ambients),
        dt=dt,
        fix_sign=fix_sign,
        causes=causes or None,
        max_iter=max_iter,
        preparations=parse_preparations(preparations),
        full_charge_soc=full_charge_soc,
    )
    echo = [lines(lambda text: click.echo(f"... {text}", err=True))]
    if decide:
        from battlab.campaign.decide import DecideOptions
        from battlab.campaign.decide import decide as run_decide

        dec = run_decide(
            DecideOptions(
                options,
                out / "runs",
                cycler_url,
                chamber_url,
                truth,
                budget_hours,
                parse_degc_list(decide_ambients),
            ),
            echo,
        )
        rep = dec.report
        rep.summary["rounds"] = dec.rounds
        if dec.undecided:
            rep.summary["undecided"] = dec.undecided
    else:
        rep = workflow.diagnose(options, echo)
    for w in rep.warnings:
        click.echo(f"warning: {w}", err=True)
    page = rep.write(out)
    click.echo(rep.text())
    click.echo(f"wrote {page}, {out / 'summary.json'} and the figures")


def parse_degc_list(text: str) -> tuple[float, ...]:
    """``"10,25,40"`` as temperatures [degC] within the chambers' -40..80 degC; one clear line otherwise."""
    from protocols.errors import InputError

    try:
        out = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError(
            f"--ambients {text!r}: expected temperatures in degC separated by commas, e.g. 10,25,40"
        ) from None
    if not out or not all(-40.0 <= x <= 80.0 for x in out):
        raise InputError(f"--ambients {text!r}: give one or more temperatures within -40..80 degC")
    return out
