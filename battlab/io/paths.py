"""Output paths: checked before a command does its work (the directory exists, the name has an accepted ending),
and the one name of a command's machine-readable summary, ``<output stem>.summary.json``."""

from __future__ import annotations

from pathlib import Path

from protocols.errors import InputError


def check_output_path(
    path: str | Path, suffixes: tuple[str, ...] | None = None, *, directory: bool = False, create: bool = False
) -> Path:
    """An output path that can be written, checked before the work starts; nothing is written here.

    ``suffixes``: the accepted endings (None: any). ``directory``: the output is a directory (the command makes
    it). ``create``: the command makes the directory the output goes into when it is missing (then the nearest
    existing one must be a directory); else that directory must exist, so a mistyped path is refused at once.
    """
    path = Path(path)
    if suffixes is not None and not path.name.endswith(suffixes):
        raise InputError(f"{path}: output must end in {_either(suffixes)}")
    parent = path.parent
    if create:
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    elif not parent.exists():
        raise InputError(f"{path}: directory {parent} does not exist")
    if not parent.is_dir():
        raise InputError(f"{path}: {parent} is a file, not a directory")
    if directory and path.exists() and not path.is_dir():
        raise InputError(f"{path}: is a file; the output is a directory")
    if not directory and path.is_dir():
        raise InputError(f"{path}: is a directory; give a file name")
    return path


#: inner suffixes that belong to the format, not the name: ``cell.bpx.json`` and ``run.bdf.csv`` have stems
#: ``cell`` and ``run``
FORMAT_INFIXES = (".bpx", ".bdf")
#: the suffix of every summary (and metadata sidecar) file
SUMMARY_SUFFIX = ".summary.json"


def output_stem(output: str | Path) -> str:
    """The name an output's companions are named after: ``plan.toml`` → ``plan``, ``cell.bpx.json`` → ``cell``,
    ``run.bdf.csv`` → ``run``, a directory ``validation`` → ``validation``."""
    path = Path(output)
    name = path.name or path.resolve().name
    stem = name[: -len(Path(name).suffix)] if Path(name).suffix else name
    for infix in FORMAT_INFIXES:
        stem = stem.removesuffix(infix)
    return stem or name


def summary_path(output: str | Path, *, directory: bool = False) -> Path:
    """The machine-readable summary (or metadata) of a command's output: ``<output stem>.summary.json`` beside a
    file output, inside a directory output (``validation/validation.summary.json``); never a fixed name that the
    next command writing to the same directory would replace."""
    path = Path(output)
    if directory:
        return path / (output_stem(path) + SUMMARY_SUFFIX)
    return path.with_name(output_stem(path) + SUMMARY_SUFFIX)


def _either(suffixes: tuple[str, ...]) -> str:
    """'.a, .b or .c'."""
    return suffixes[0] if len(suffixes) == 1 else f"{', '.join(suffixes[:-1])} or {suffixes[-1]}"


__all__ = ["SUMMARY_SUFFIX", "check_output_path", "output_stem", "summary_path"]
