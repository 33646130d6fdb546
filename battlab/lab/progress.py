"""The run's progress display: a rich live panel on a terminal, one line per step otherwise."""

from __future__ import annotations

import math
import time
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from battlab.lab.documents import RunStart, RunStop, StepStart, StepStop, Subscriber


class ProgressDisplay(Subscriber):
    """Step k of n, its label and time, the latest V / I / T, rows logged; refreshed at most every
    ``refresh_s`` real seconds (the display costs nothing per sample in between)."""

    def __init__(
        self, name: str, n_entries: int, *, console: Console | None = None, refresh_s: float = 0.25, quiet: bool = False
    ) -> None:
        self.name = name
        self.n_entries = n_entries
        self.console = console or Console(stderr=True)
        self.refresh_s = refresh_s
        self.quiet = quiet
        self.live: Live | None = None
        self._step: StepStart | None = None
        self._row: tuple[float, ...] | None = None
        self._rows = 0
        self._last = 0.0
        self._wall0 = time.perf_counter()

    def _render(self) -> Table:
        table = Table.grid(padding=(0, 2))
        table.add_column(style="bold")
        table.add_column()
        table.add_row("plan", escape(self.name))
        if self._step is not None:
            e = self._step.entry
            table.add_row("step", escape(f"{e.entry + 1} of {self.n_entries}: {e.label} [{self._step.kind}]"))
        if self._row is not None:
            test_t, _, step_t, v, i, T_s, T_a = self._row[:7]
            dur = self._step.duration_s if self._step is not None else None
            table.add_row("step time", f"{step_t:,.0f} s" + (f" of {dur:,.0f} s" if dur else ""))
            table.add_row("test time", f"{test_t:,.0f} s ({test_t / 3600:.2f} h)")
            temps = "" if math.isnan(T_s) else f"   T {T_s:.1f} degC"
            temps += "" if math.isnan(T_a) else f"   air {T_a:.1f} degC"
            table.add_row("now", f"V {v:.4f} V   I {i:+.3f} A{temps}")
        table.add_row("logged", f"{self._rows:,} rows, {time.perf_counter() - self._wall0:,.1f} s wall")
        return table

    def start(self, doc: RunStart) -> None:
        if self.quiet:
            return
        if self.console.is_terminal:
            self.live = Live(self._render(), console=self.console, auto_refresh=False, transient=False)
            self.live.start()
        else:
            self.console.print(f"run {doc.run_id}: {self.name}, {self.n_entries} steps")

    def step_start(self, doc: StepStart) -> None:
        self._step = doc
        if not self.quiet and self.live is None:
            e = doc.entry
            self.console.print(f"  step {e.entry + 1}/{self.n_entries}: {e.label} [{doc.kind}]", markup=False)

    def event(self, row: tuple[float, ...]) -> None:
        self._row = row
        self._rows += 1
        if self.live is not None:
            now = time.perf_counter()
            if now - self._last >= self.refresh_s:
                self._last = now
                self.live.update(self._render(), refresh=True)

    def step_stop(self, doc: StepStop) -> None:
        if not self.quiet and self.live is None and doc.status == "completed":
            self.console.print(f"    ended: {doc.ended_by}", markup=False)

    def stop(self, doc: RunStop) -> None:
        if self.live is not None:
            self.live.update(self._render(), refresh=True)
            self.live.stop()
            self.live = None
        if not self.quiet:
            tail = f": {doc.reason}" if doc.reason else ""
            self.console.print(f"run {doc.status}{tail}", markup=False)


def describe(summary: dict[str, Any]) -> str:
    """One line from a stop summary's stats."""
    s = summary.get("stats", {})
    return (
        f"{s.get('samples', 0):,} samples, {s.get('retries', 0)} retries, "
        f"max lateness {s.get('max_late_s', 0.0):.2f} s, {s.get('gaps', 0)} gaps marked, "
        f"runner overhead {1e6 * s.get('overhead_per_sample_s', 0.0):.0f} us/sample"
    )


__all__ = ["ProgressDisplay", "describe"]
