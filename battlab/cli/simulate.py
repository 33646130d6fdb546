"""``battlab simulate CELL PROFILE.csv``: run the DFN–thermal model on a current profile."""

from __future__ import annotations

from pathlib import Path

import click

from protocols.errors import InputError
from protocols.profile import Profile


@click.command("simulate")
@click.argument("cell")
@click.argument("profile")
@click.option("--soc0", type=float, default=None, help="Start SOC in [0, 1] (default: from the profile, else 1).")
@click.option("--ambient", type=float, default=25.0, show_default=True, help="Ambient temperature [degC].")
@click.option("--isothermal", is_flag=True, help="Hold the cell at the ambient temperature.")
@click.option("--sens", default="", help="Comma-separated parameters for dV/dθ̄ (e.g. R_s_n,D_s_n) or 'all'.")
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="OUT.bdf.csv or OUT.h5 (BDF column names, current positive = charge).",
)
def simulate(
    cell: str, profile: str, soc0: float | None, ambient: float, isothermal: bool, sens: str, output: str
) -> None:
    """Simulate CELL (a built-in name or a BPX file) under PROFILE.

    PROFILE is a CSV with the columns 'Test Time / s' and 'Current / A' (positive = charge), or
    ``library:ID`` for a profile of the OED input library (which then also gives the start SOC).
    """
    from rich.console import Console

    from battlab import parameters
    from battlab.cell import Cell
    from battlab.io.results import write_result
    from battlab.simulation import simulate as run

    c = Cell.load(cell)
    prof = _profile(profile)
    if soc0 is None:
        soc0 = prof.soc0 if prof.soc0 is not None else 1.0
    names = list(parameters.NAMES) if sens.strip() == "all" else [s.strip() for s in sens.split(",") if s.strip()]
    if not -40.0 <= ambient <= 80.0:
        raise InputError(f"--ambient {ambient} degC is outside -40..80 degC")
    console = Console(stderr=True)
    with console.status(f"simulating {Path(profile).name} on {c.name} ({prof.duration:.0f} s)"):
        res = run(c, prof, soc0=soc0, ambient=ambient + 273.15, isothermal=isothermal, sensitivities=names)
    out = write_result(
        res,
        output,
        ambient + 273.15,
        {"cell": c.name, "cell_hash": c.hash(), "profile": str(profile), "soc0": soc0, "isothermal": isothermal},
    )
    end = "completed" if res.ended_by is None else f"ended early: {res.ended_by} at t = {res.t[-1]:.1f} s"
    console.print(
        f"{out}: {res.t.size} samples, V {res.voltage.min():.4f}–{res.voltage.max():.4f} V, "
        f"T_surface max {res.T_surface.max() - 273.15:.2f} degC; {end} "
        f"(build {res.stats['build_seconds']:.2f} s, solve {res.stats['solve_seconds']:.2f} s)"
    )


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
