"""Export profiles and protocols to tester schedule files (and PyBaMM, CSV), and read them back.

``export(source, fmt, out_dir)`` writes one of :class:`Format`; ``read_back(fmt, path)`` re-imports what was
written (for the round-trip checks). Each format's module documents its conventions (sign, units,
resolution, limits): :mod:`.maccor`, :mod:`.arbin`, :mod:`.biologic`, :mod:`.neware`, :mod:`.pybamm`,
:mod:`.csv`. An exporter refuses, with an :class:`InputError` saying what to change, whatever its format
cannot represent exactly (too many steps, timing finer than its resolution, an end it has no field for); it
never writes a different profile.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from datetime import datetime
from pathlib import Path
from types import ModuleType

from protocols.export import arbin, biologic, maccor, neware
from protocols.export import csv as csv_format
from protocols.export import pybamm as pybamm_format
from protocols.export.base import (
    ExportResult,
    Format,
    FormatRules,
    ReadBack,
    as_protocol,
    check_cycler_current,
)
from protocols.export.program import canonical, difference, split_cccv
from protocols.profile import Profile
from protocols.protocol import Protocol, SafetyLimits

MODULES: dict[Format, ModuleType] = {
    Format.MACCOR: maccor,
    Format.ARBIN: arbin,
    Format.BIOLOGIC: biologic,
    Format.NEWARE: neware,
    Format.PYBAMM: pybamm_format,
    Format.CSV: csv_format,
}


def rules(fmt: Format | str) -> FormatRules:
    """Resolution and limits of a format."""
    return MODULES[Format.parse(fmt)].RULES


def export(
    source: Profile | Protocol,
    fmt: Format | str,
    out_dir: str | Path,
    *,
    name: str | None = None,
    max_steps: int | None = None,
    limits: SafetyLimits | None = None,
    created: datetime | None = None,
    max_current_a: float | None = None,
) -> ExportResult:
    """Write ``source`` in format ``fmt`` into ``out_dir`` (created if missing).

    ``max_steps`` overrides the format's step/segment limit; ``limits`` are the safety limits used when
    ``source`` is a bare profile; ``created`` stamps formats that carry a date (Neware); ``max_current_a``
    is the cycler channel's current range [A] (steps beyond it are refused).

    The files are written into a staging directory and moved into ``out_dir`` only when the whole export
    succeeded: a refusal found while writing (a time finer than the format's, too many steps) leaves neither
    files nor directories behind.
    """
    f = Format.parse(fmt)
    protocol = as_protocol(source, limits).check()
    if max_current_a is not None:
        check_cycler_current(protocol, max_current_a)
    out = Path(out_dir)
    module = MODULES[f]
    kwargs = {"name": name, "rules": module.RULES.with_max_steps(max_steps)}
    if f is Format.NEWARE:
        kwargs["created"] = created
    anchor = out
    while not anchor.exists() and anchor != anchor.parent:
        anchor = anchor.parent  # the staging directory goes on the same file system as out_dir
    staging = Path(tempfile.mkdtemp(prefix=".export-", dir=anchor))
    try:
        result = module.write(protocol, staging, **kwargs)
        out.mkdir(parents=True, exist_ok=True)
        files = []
        for written in result.files:
            target = out / written.relative_to(staging)
            os.replace(written, target)
            files.append(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return ExportResult(tuple(files), result.notes)


def read_back(fmt: Format | str, path: str | Path) -> ReadBack:
    """Re-import a file written by :func:`export` (PyBaMM needs ``pybamm`` installed)."""
    return MODULES[Format.parse(fmt)].read(path)


def expected(protocol: Protocol, fmt: Format | str) -> list:
    """The canonical form a faithful re-import of ``protocol`` from ``fmt`` must equal."""
    f = Format.parse(fmt)
    return canonical(split_cccv(protocol) if f in (Format.BIOLOGIC, Format.PYBAMM) else protocol)


__all__ = [
    "ExportResult",
    "Format",
    "FormatRules",
    "ReadBack",
    "difference",
    "expected",
    "export",
    "read_back",
    "rules",
]
