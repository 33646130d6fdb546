"""``battlab validate``: the voltage RMSE of cells on logged data sets (Tables 12-14), each prediction from the
data's own start state, with figures and a summary."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.identify.data_files import Ambient, ambient_of, check_ambient_keys, load_all
from battlab.jsonable import json_default


@dataclass
class ValidationReport:
    """RMSE [mV] per cell and data set over the samples each prediction reached, the fraction it reached
    (``coverage``, 1.0 unless the model stopped early) and why it stopped (``ended_by``), the errors, and each
    data set's predictions (NaN where not reached)."""

    table: dict[str, dict[str, float]]
    errors: dict[str, np.ndarray]
    predictions: dict[str, tuple[Any, dict[str, np.ndarray]]]
    warnings: list[str] = field(default_factory=list)
    coverage: dict[str, dict[str, float]] = field(default_factory=dict)
    ended_by: dict[str, dict[str, str]] = field(default_factory=dict)

    def write(self, outdir: str | Path) -> Path:
        """Figures (Figs. 7 and 9), ``report.html`` showing them with the RMSE table, and ``<outdir>.summary.json``
        in ``outdir``; returns the summary's path."""
        from battlab.identify.validation import plot_cdf, plot_validation
        from battlab.io.paths import summary_path

        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        figures = {
            name: plot_validation(e, preds, outdir / f"{name.replace('#', '_')}.png")
            for name, (e, preds) in self.predictions.items()
        }
        figures["|voltage error| of every data set"] = plot_cdf(
            self.errors, outdir / "error_cdf.png", "validation: |voltage error|"
        )
        self._page(outdir / "report.html", figures)
        path = summary_path(outdir, directory=True)
        summary = {"rmse_mV": self.table, "coverage": self.coverage, "ended_by": self.ended_by}
        path.write_text(json.dumps(summary, indent=2, default=json_default))
        return path

    def _page(self, path: Path, figures: dict[str, Path]) -> Path:
        """The static page: RMSE [mV] per data set and cell (with the share of the data each prediction reached),
        the warnings, and the figures."""
        from battlab.report import html

        labels = list(self.table)
        names = list(next(iter(self.table.values()))) if labels else []
        rows = [[n, *(self.table[lab][n] for lab in labels), *(self.coverage[lab][n] for lab in labels)] for n in names]
        columns = ["data", *(f"{lab} RMSE [mV]" for lab in labels), *(f"{lab} share reached" for lab in labels)]
        sections = [
            html.Section(
                "Voltage RMSE",
                [html.Table(columns, rows, note="each prediction from the data's own start state")],
            ),
            html.Section("Figures", [html.Figure(p, name) for name, p in figures.items()]),
        ]
        if self.warnings:
            sections.insert(1, html.Section("Warnings", [html.Paragraph(w, "warn") for w in self.warnings]))
        return html.write(path, "Validation", sections, subtitle=", ".join(labels) + " on " + ", ".join(names))


def cell_label(spec: str) -> str:
    return Path(spec).name.removesuffix(".json").removesuffix(".bpx") if spec.endswith(".json") else spec


def validate(
    data: Sequence[str | Path],
    cells: Sequence[str],
    *,
    soc0: float | None = None,
    ambient: Ambient = None,
    dt: float = 1.0,
    fix_sign: bool = False,
) -> ValidationReport:
    """The voltage RMSE of each cell on each data set (predictions from the data's start state), over the
    samples the prediction reached; each (cell, data set) is simulated on its own, so the order of the files
    does not matter. ``ambient`` [K]: for data that do not log it (see :data:`Ambient`)."""
    from battlab.identify.experiments import experiments_from_data
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import prediction

    check_ambient_keys(data, ambient)
    loaded, warned = load_all(data, fix_sign=fix_sign)
    rep = ValidationReport({}, {}, {}, warned)
    for spec in cells:
        cell = Cell.load(spec)
        label = cell_label(spec)
        fm = ForwardModel(cell, v_margin=0.15)
        rep.table[label], rep.coverage[label], rep.ended_by[label] = {}, {}, {}
        errs = []
        for d in loaded:
            for e in experiments_from_data(d, cell, dt=dt, soc0=soc0, ambient=ambient_of(d, ambient)):
                p, why = prediction(fm, cell, e)
                reached = np.isfinite(p)
                err = 1e3 * (p[reached] - e.voltage[reached])
                rep.table[label][e.name] = float(np.sqrt(np.mean(err**2))) if err.size else float("nan")
                rep.coverage[label][e.name] = float(reached.mean())
                if why is not None:
                    rep.ended_by[label][e.name] = why
                    rep.warnings.append(
                        f"{e.name}: cell {label} stopped at {100 * reached.mean():.1f} % of the data ({why}); "
                        "its RMSE covers that part only"
                    )
                errs.append(err)
                rep.predictions.setdefault(e.name, (e, {}))[1][label] = p
        rep.errors[label] = np.concatenate(errs) if errs else np.zeros(0)
    return rep
