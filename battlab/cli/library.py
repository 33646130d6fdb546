"""``battlab library``: build, list, show and plot the OED input library (:mod:`protocols.library`)."""

from __future__ import annotations

import time
from pathlib import Path

import click

from battlab.cli.options import soc0_option
from battlab.io.paths import check_output_path
from protocols import InputError, Library, Profile
from protocols.constants import RATED_CAPACITY_AH


def _open(path: str | None) -> Library:
    """The library in ``path``, or a fresh (deterministic) build when no file is given."""
    return Library.load(path) if path else Library.build()


_LIBRARY_OPTION = click.option(
    "-l",
    "--library",
    "library_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Library HDF5 file (default: build the library in memory; ids are stable).",
)


@click.group(name="library")
def library() -> None:
    """The OED input library: 540 pulses, 180 sinusoids, 18 drive cycles, each L1-normalised to 1 Ah."""


@library.command("build")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="HDF5 file to write.")
def build(output: str) -> None:
    """Generate the library, print the count after each filter and the total duration, save it."""
    check_output_path(output)
    t0 = time.perf_counter()
    lib = Library.build()
    t_build = time.perf_counter() - t0
    path = lib.save(output)
    click.echo(f"{'filter':<12}{'pulse':>7}{'sine':>7}{'drive':>7}{'total':>7}")
    for c in lib.counts:
        click.echo(f"{c.filter:<12}{c.pulse:>7}{c.sine:>7}{c.drive:>7}{c.total:>7}")
    click.echo(f"{len(lib)} profiles, {lib.total_hours:.2f} h in total (paper: 738 profiles, 329.65 h)")
    click.echo(f"built in {t_build:.2f} s, wrote {path}")


@library.command("list")
@_LIBRARY_OPTION
@click.option("--kind", type=click.Choice(["pulse", "sine", "drive"]), default=None, help="Only this kind.")
@soc0_option("Only this start SOC")
def list_(library_path: str | None, kind: str | None, soc0: float | None) -> None:
    """One line per profile: id, kind, start SOC, duration, peak current, net charge, flag, name."""
    lib = _open(library_path)
    click.echo(f"{'id':>4}  {'kind':<6}{'soc0':>5}{'dur/s':>7}{'|I|max/A':>9}{'net/Ah':>8}  {'screen':<6}  name")
    for p in lib.select(kind=kind, soc0=soc0):
        s = lib.screening.get(int(p.id))  # type: ignore[arg-type]
        flag = "-" if s is None else ("ok" if s.ok else "FLAG")
        click.echo(
            f"{p.id:>4}  {p.kind:<6}{p.soc0:>5.1f}{p.duration:>7.0f}{p.max_abs_current:>9.3f}"
            f"{p.net_charge:>8.3f}  {flag:<6}  {p.params.get('name', '')}"
        )


@library.command("show")
@click.argument("profile_id", type=int)
@_LIBRARY_OPTION
def show(profile_id: int, library_path: str | None) -> None:
    """Metadata, generating parameters and summary numbers of one profile."""
    lib = _open(library_path)
    p = lib[profile_id]
    click.echo(f"id            {p.id}")
    click.echo(f"kind          {p.kind}")
    click.echo(f"start SOC     {p.soc0}")
    click.echo(f"duration      {p.duration:g} s ({p.t.size} samples)")
    click.echo(f"|I| max       {p.max_abs_current:.4f} A ({p.max_abs_current / RATED_CAPACITY_AH:.3f} C)")
    click.echo(f"throughput    {p.charge_throughput:.6f} Ah")
    click.echo(f"net charge    {p.net_charge:.6f} Ah")
    soc = p.soc(RATED_CAPACITY_AH)
    click.echo(f"SOC range     {soc.min():.4f} .. {soc.max():.4f}")
    s = lib.screening.get(profile_id)
    click.echo(f"screen        {'not run' if s is None else ('ok' if s.ok else f'flagged: {s.reason}')}")
    for key, value in p.params.items():
        click.echo(f"  {key:<26}{value}")


@library.command("plot")
@click.argument("profile_id", type=int)
@_LIBRARY_OPTION
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, help="PNG (default profile_<ID>.png).")
def plot(profile_id: int, library_path: str | None, output: str | None) -> None:
    """PNG of current and SOC vs time for one profile."""
    path = check_output_path(output or f"profile_{profile_id}.png")
    lib = _open(library_path)
    p = lib[profile_id]
    plot_profile(p, path)
    click.echo(f"wrote {path}")


def plot_profile(p: Profile, path: Path) -> Path:
    """Draw current (zero-order hold) and SOC vs time into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: the plot is written as PNG; use a .png file name")
    fig, (ax_i, ax_s) = plt.subplots(2, 1, sharex=True, figsize=(8, 5), constrained_layout=True)
    ax_i.step(p.t, p.current, where="post", lw=0.8)
    ax_i.set_ylabel("current / A (+ = charge)")
    ax_i.set_title(f"profile {p.id}: {p.params.get('name', p.kind)} (start SOC {p.soc0})")
    ax_s.plot(p.t, p.soc(RATED_CAPACITY_AH), lw=1.0)
    ax_s.set_ylabel("SOC / -")
    ax_s.set_xlabel("time / s")
    for ax in (ax_i, ax_s):
        ax.grid(alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


__all__ = ["library"]
