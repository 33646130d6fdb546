"""What a fit returns and announces: the :class:`FitReport` (cell, summary, BPX metadata, stages; written
atomically), the :class:`StageFailed` error that keeps the finished stages, and the payloads of the progress notes
that announce each finished step (:class:`StageDone`, :class:`EquilibriumDone`, :class:`ValuesDone`)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from battlab.cell import Cell
from battlab.identify.fit_summary import stages_text
from battlab.jsonable import json_default
from protocols.errors import InputError


@dataclass(frozen=True)
class StageDone:
    """A dynamic stage finished (1-based ``stage`` of ``total``), its result written when an output is given."""

    stage: int
    total: int
    result: Any  # identify.fit.FitResult


@dataclass(frozen=True)
class EquilibriumDone:
    """The equilibrium fit of the OCV test ``data`` finished."""

    data: str
    result: Any  # identify.equilibrium result


@dataclass(frozen=True)
class ValuesDone:
    """A fit of cell values outside the 18 (or the Arrhenius refits) finished."""

    result: Any


@dataclass
class FitReport:
    """A fit's outcome: the identified cell, the machine-readable summary, the BPX metadata, the stages; where it
    was last written (``written``: BPX and summary paths; ``kept``: the stages those hold)."""

    cell: Cell
    summary: dict[str, Any]
    extra: dict[str, Any]
    results: list[Any] = field(default_factory=list)  # identify.fit.FitResult per stage
    equilibrium: Any = None  # identify.equilibrium result, when an OCV test was given
    equilibrium_data: str = ""  # the name of that OCV test
    warnings: list[str] = field(default_factory=list)
    written: tuple[Path, Path] | None = None
    kept: int = 0
    experiments: list[Any] = field(default_factory=list)  # the dynamic experiments fitted (weighted)

    @property
    def last(self) -> Any:
        return self.results[-1] if self.results else None

    def write(self, output: str | Path) -> tuple[Path, Path]:
        """The BPX cell (intervals and fit report under "User-defined"), ``<cell>.summary.json`` beside it and the
        same summary as ``summary.json`` (the name scripts read: docs/file-formats.md).

        Each file is written to a temporary name and renamed over the old one, so a crash while writing leaves
        the previous version (e.g. the last finished stage) whole."""
        from battlab.io.paths import summary_path as summary_of

        out = Path(output)
        tmp = out.with_name(f".{out.name}.tmp")
        self.cell.renamed(out.name.removesuffix(".json").removesuffix(".bpx")).to_bpx(tmp, **self.extra)
        os.replace(tmp, out)
        summary_path = summary_of(out)
        text = json.dumps(self.summary, indent=2, default=json_default)
        for path in (summary_path, out.with_name("summary.json")):
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)
        self.written = (out, summary_path)
        return out, summary_path

    def checkpoint(self, output: str | Path | None, kept: int) -> None:
        """Write the report as it stands (``kept`` stages done), when an output is given."""
        if output is not None:
            self.write(output)
            self.kept = kept


class StageFailed(Exception):
    """``fit`` failed in a stage: the stage (1-based, of ``total``), its cause, the report of the finished stages
    (partial), the files the last of them was written to and how many stages those hold (``written`` None: nothing
    written; ``kept`` 0 with files: the equilibrium fit alone)."""

    def __init__(
        self,
        stage: int,
        total: int,
        cause: Exception,
        report: FitReport,
        written: tuple[Path, Path] | None,
        kept: int,
    ) -> None:
        self.stage, self.total, self.cause, self.report = stage, total, cause, report
        self.written, self.kept = written, kept
        what = " ".join(str(cause).split())  # one line, whatever the cause's text
        what = what if isinstance(cause, InputError) else f"{type(cause).__name__}: {what}"
        if written is not None:
            where = f"{stages_text(kept, total)} kept (partial) in {written[0]} and {written[1]}"
        elif report.results:
            where = f"{stages_text(len(report.results), total)} finished, nothing written (no output given)"
        else:
            where = "no stage finished, nothing written"
        super().__init__(f"fit failed in stage {stage} of {total}: {what}; {where}")


def on_stage(fn: Any) -> Any:
    """A progress subscriber that calls ``fn(stage, result)`` as each dynamic stage finishes (written)."""

    def sub(ev: Any) -> None:
        if isinstance(ev.payload, StageDone):
            fn(ev.payload.stage, ev.payload.result)

    return sub


def on_equilibrium(fn: Any) -> Any:
    """A progress subscriber that calls ``fn(data name, result)`` when the equilibrium fit is done (written)."""

    def sub(ev: Any) -> None:
        if isinstance(ev.payload, EquilibriumDone):
            fn(ev.payload.data, ev.payload.result)

    return sub
