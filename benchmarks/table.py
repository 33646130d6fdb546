"""Result rows, tables and timing helpers shared by the benchmark scripts."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


# ---------------------------------------------------------------------------------------------------------------
# table
@dataclass
class Row:
    """One line of the summary."""

    metric: str
    battlab: float | None
    pybamm: float | None
    unit: str
    target: str = ""
    met: bool | None = None
    note: str = ""

    @property
    def ratio(self) -> float | None:
        if self.battlab is None or self.pybamm is None or self.pybamm == 0:
            return None
        return self.battlab / self.pybamm


def fmt(v: float | None, unit: str = "") -> str:
    if v is None:
        return "–"
    if unit == "count":
        return f"{v:.0f}"
    if abs(v) >= 100:
        return f"{v:.0f}"
    if abs(v) >= 1:
        return f"{v:.2f}"
    return f"{v:.3g}"


def print_table(title: str, rows: list[Row]) -> None:
    print(f"\n{title}")
    head = ("metric", "battlab", "PyBaMM", "ratio", "unit", "target", "met?")
    body = [
        (
            r.metric,
            fmt(r.battlab, r.unit),
            fmt(r.pybamm, r.unit),
            "–" if r.ratio is None else f"{r.ratio:.2f}×",
            r.unit,
            r.target,
            "–" if r.met is None else ("yes" if r.met else "NO"),
        )
        for r in rows
    ]
    widths = [max(len(x[i]) for x in [head, *body]) for i in range(len(head))]
    line = "  ".join("{:<" + str(w) + "}" for w in widths)
    print(line.format(*head))
    print(line.format(*("-" * w for w in widths)))
    for b, r in zip(body, rows, strict=True):
        print(line.format(*b) + (f"  ({r.note})" if r.note else ""))


def log(msg: str) -> None:
    print(msg, flush=True)


def best_of(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """(best wall time [s], last result) of ``repeat`` calls."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out
