"""``battlab simulate CELL PROFILE.csv``: run the DFN–thermal model on a current profile."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import click

from battlab.cli.options import (
    TEMPERATURE,
    ambient_option,
    apply_extensions,
    apply_ocps,
    bounded_option,
    extension_option,
    ocp_option,
    parse_v_limits,
    soc0_option,
    v_limits_option,
)
from protocols.errors import InputError
from protocols.profile import Profile

if TYPE_CHECKING:
    from battlab.cell import Cell


@click.command("simulate")
@click.argument("cell")
@click.argument("profile")
@soc0_option("Start SOC (default: from the profile, else 1)")
@ambient_option()
@bounded_option("--T0", TEMPERATURE, "Initial cell temperature [degC] (default: the ambient)", "t0")
@click.option("--isothermal", is_flag=True, help="Hold the cell at the ambient temperature.")
@v_limits_option(
    "Stop outside these voltages [V] instead of the cell's window (to follow logged data through the "
    "excursions it shows, e.g. regen at full charge); 0 <= MIN < MAX <= 10 V."
)
@click.option(
    "--sens",
    default="",
    help="Comma-separated parameters for dV/dθ̄ (e.g. R_s_n,D_s_n,contact_resistance.R_c) or 'all'.",
)
@extension_option()
@ocp_option()
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="OUT.bdf.csv or OUT.h5 (BDF column names, current positive = charge).",
)
def simulate(
    cell: str,
    profile: str,
    soc0: float | None,
    ambient: float,
    t0: float | None,
    isothermal: bool,
    v_limits: str | None,
    sens: str,
    extensions: tuple[str, ...],
    ocps: tuple[str, ...],
    output: str,
) -> None:
    """Simulate CELL (a built-in name or a BPX file) under PROFILE.

    PROFILE is a CSV with the columns 'Test Time / s' and 'Current / A' (positive = charge), or
    ``library:ID`` for a profile of the OED input library (which then also gives the start SOC).
    """
    from battlab.cell import Cell
    from battlab.cli.console import make_console
    from battlab.io.results import check_output_path, write_result
    from battlab.simulation import simulate as run

    check_output_path(output)
    c = apply_extensions(apply_ocps(Cell.load(cell), ocps), extensions, isothermal)
    prof = _profile(profile)
    if soc0 is None:
        soc0 = prof.soc0 if prof.soc0 is not None else 1.0
    names = list(c.parameter_names()) if sens.strip() == "all" else [s.strip() for s in sens.split(",") if s.strip()]
    _check_current(prof, c, profile)
    limits = parse_v_limits(v_limits) if v_limits is not None else None
    console = make_console(stderr=True)
    _announce_compiles()
    T0 = None if t0 is None else t0 + 273.15
    with console.status(f"simulating {Path(profile).name} on {c.name} ({prof.duration:.0f} s)"):
        try:
            res = run(
                c,
                prof,
                soc0=soc0,
                ambient=ambient + 273.15,
                isothermal=isothermal,
                sensitivities=names,
                T0=T0,
                v_limits=limits,
            )
        except InputError as exc:
            raise InputError(f"{profile}: {exc}") from None
    timing = f"build {res.stats['build_seconds']:.2f} s, solve {res.stats['solve_seconds']:.2f} s"
    if res.t.size < 2:
        raise InputError(
            f"{profile}: the run ends at its first sample ({res.ended_by}), nothing to write: check --soc0 "
            f"({soc0:g}) and the current's sign (positive = charge)"
        )
    meta = {"cell": c.name, "cell_hash": c.hash(), "profile": str(profile), "soc0": soc0, "isothermal": isothermal}
    meta |= {"extensions": {k: dict(v) for k, v in c.extensions.items()}} if c.extensions else {}
    meta |= {"T0_degC": t0, "v_limits": list(limits) if limits else None}
    out = write_result(res, output, ambient + 273.15, meta)
    covered = f"{res.t.size} of {prof.t.size} samples"
    if res.ended_by is not None and res.ended_by.startswith("solver"):
        raise click.ClickException(
            f"{profile}: the simulation failed at t = {res.t[-1]:.1f} s ({res.ended_by}); the {covered} before "
            f"it are in {out} ({timing})"
        )
    end = "completed" if res.ended_by is None else f"ended early: {res.ended_by} at t = {res.t[-1]:.1f} s"
    console.print(
        f"{out}: {covered}, V {res.voltage.min():.4f}–{res.voltage.max():.4f} V, "
        f"T_surface max {res.T_surface.max() - 273.15:.2f} degC; {end} ({timing})",
        soft_wrap=True,
    )


#: a profile above this many C for the cell is taken for a unit mistake (mA, or another cell's profile)
MAX_C_RATE = 20.0


def _check_current(prof: Profile, cell: Cell, where: str) -> None:
    q = float(cell["Q_nom"])
    peak = float(abs(prof.current).max())
    if peak > MAX_C_RATE * q:
        raise InputError(
            f"{where}: the current reaches {peak:.4g} A = {peak / q:.0f}C of the {q:g} Ah cell {cell.name!r} (more "
            f"than {MAX_C_RATE:g}C): wrong units (mA?) or another cell's profile"
        )


class _CompileNotice(logging.Handler):
    """Echo the model's compile notice on stderr (the first run of a cell and mesh on a machine takes 10–30 s)."""

    def emit(self, record: logging.LogRecord) -> None:
        click.echo(record.getMessage(), err=True)


_NOTICE = _CompileNotice(logging.INFO)


def _announce_compiles() -> None:
    logger = logging.getLogger("battlab.model")
    if _NOTICE not in logger.handlers:
        logger.addHandler(_NOTICE)
        logger.setLevel(logging.INFO)


def _profile(spec: str) -> Profile:
    """A profile from a CSV path or ``library:ID``."""
    if spec.startswith("library:"):
        from protocols import Library

        ident = spec.removeprefix("library:")
        try:
            return Library.build()[int(ident)]
        except (ValueError, KeyError):
            raise InputError(f"{spec}: expected library:ID with an id between 1 and 738") from None
    return Profile.from_csv(spec)
