"""``battlab export``: write a profile or a protocol (plan) as a tester schedule, a PyBaMM module or a CSV."""

from __future__ import annotations

from pathlib import Path

import click

from battlab.io.paths import check_output_path
from protocols import InputError, Library, Profile, Protocol
from protocols.export import Format
from protocols.export import export as export_to

FORMATS = ", ".join(f.value for f in Format)


def load_source(source: str, library_path: str | None) -> Profile | Protocol:
    """A profile CSV, a protocol or plan TOML/JSON (a plan's ``[run]`` table is the runner's, not exported), or a
    library profile id."""
    path = Path(source)
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".csv":
            return Profile.from_csv(path, id=path.stem)
        if suffix in (".toml", ".json"):
            from battlab.io.plan import Plan

            return Plan.load(path, library=library_path).protocol
        raise InputError(f"{path}: expected a profile .csv or a protocol/plan .toml or .json")
    if source.isdigit():
        lib = Library.load(library_path) if library_path else Library.build()
        return lib[int(source)]
    raise InputError(f"{source}: no such file, and not a library profile id")


@click.command("export")
@click.argument("source", metavar="PROFILE_OR_PLAN")
@click.option("-f", "--format", "fmt", required=True, help=f"Output format: {FORMATS}.")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Directory.")
@click.option(
    "-l",
    "--library",
    "library_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Library HDF5 for library ids (default: the built library).",
)
@click.option("--name", default=None, help="Base name of the written files (default: the protocol's name).")
@click.option(
    "--max-steps",
    type=int,
    default=None,
    help="Override the format's step/segment limit (if your tester takes more).",
)
@click.option("--max-current", type=float, default=None, help="The cycler channel's current range [A].")
def export(
    source: str,
    fmt: str,
    out_dir: str,
    library_path: str | None,
    name: str | None,
    max_steps: int | None,
    max_current: float | None,
) -> None:
    """Export PROFILE_OR_PLAN (a profile .csv, a protocol/plan .toml/.json, or a library id).

    Formats: maccor (.000 procedure + .MWF FastWave waveform), arbin (.sdu), biologic (Modulo Bat .mps),
    neware (BTS .xml), pybamm (module with experiment()), csv (Test Time / s, Current / A). A file the format
    cannot represent exactly is refused with what to change.
    """
    check_output_path(out_dir, directory=True, create=True)
    f = Format.parse(fmt)
    obj = load_source(source, library_path)
    try:
        result = export_to(obj, f, out_dir, name=name, max_steps=max_steps, max_current_a=max_current)
    except InputError as exc:
        # what the exporters refuse names the protocol and the step; the file they came from is the user's
        if Path(source).is_file() and source not in str(exc):
            raise InputError(f"{source}: {exc}") from None
        raise
    for path in result.files:
        click.echo(f"wrote {path}")
    for note in result.notes:
        click.echo(f"note: {note}")


__all__ = ["export"]
