"""What a diagnosis returns: each fitted cause's confirmation on held-out data, and the report (the one-screen
text, ``summary.json`` as DESIGN.md's contract, the static HTML page with its PNG figures)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from battlab.diagnose.confirmation import Confirmation
from battlab.jsonable import json_default


def headline(summary: Mapping[str, Any]) -> tuple[str, str]:
    """The verdict in one line and its colour (``"good"`` green, ``"warn"`` amber, ``"bad"`` red), from the summary's
    numbers: ``cause``, ``cannot_tell`` and ``residual_over_noise`` (the mean squared residual over the data's own
    noise variance, s²). Green only when no cause is named, the data leave none undecided and s² is at most
    :data:`battlab.diagnose.confirm.S2_REFIT`; red when a cause is named or s² is above that (the model is wrong
    whatever was named); amber when the data cannot decide or their noise level is unknown."""
    from battlab.diagnose.confirm import S2_REFIT

    cause = summary.get("cause")
    s2 = summary.get("residual_over_noise")
    known = isinstance(s2, (int, float)) and math.isfinite(s2)
    noise = f"residual s² {s2:.3g} over the noise variance" if known else "noise level unknown"
    undecided = ", ".join(c["cause"] for c in summary.get("cannot_tell", []))
    cannot = f"; cannot tell {undecided} on these data" if undecided else ""
    if cause:
        return f"cause: {cause} ({noise}){cannot}", "bad"
    if known and s2 > S2_REFIT:
        return f"no cause named, but the model is wrong here: {noise}{cannot}", "bad"
    if undecided or not known:
        return f"no cause named ({noise}){cannot}", "warn"
    return f"no significant discrepancy among the causes tested ({noise})", "good"


def untestable_causes(summary: Mapping[str, Any]) -> set[str]:
    """The causes these data cannot test (``untestable``): never shown as passing their score test."""
    return {c["cause"] for c in summary.get("untestable", [])}


#: the columns of :func:`rounds_table`
ROUND_COLUMNS = ["round", "causes", "profile", "ambient [degC]", "expected chi2", "lab hours", "cause after"]


def rounds_table(rounds: list[dict[str, Any]]) -> tuple[list[str], list[list[Any]]]:
    """The deciding experiments run (``summary["rounds"]``) as (columns, rows): the causes each round set apart,
    its profile and ambient, the divergence it was expected to show (χ²), its lab hours and the cause named after."""
    rows = [
        [
            r["round"],
            " vs ".join(r["causes"]),
            r["experiment"]["profile"],
            r["experiment"]["ambient_degC"],
            r["experiment"]["divergence"],
            r["experiment"]["lab_hours"],
            r.get("cause_after"),
        ]
        for r in rounds
    ]
    return ROUND_COLUMNS, rows


@dataclass
class DiagnosisReport:
    """The diagnosis: summary (the contract's ``summary.json``), residual analysis, score tests, confirmations."""

    summary: dict[str, Any]
    analysis: Any  # residuals.ResidualAnalysis over all data
    scores: list[Any]  # score.ScoreResult per cause tested, ranked
    confirmations: list[Confirmation]
    base_fit: Confirmation | None
    cell_name: str
    warnings: list[str] = field(default_factory=list)

    def text(self) -> str:
        """A one-screen summary."""
        s = self.summary
        a = s["residual"]
        lines = [
            f"diagnosis of cell {self.cell_name!r} on {', '.join(s['data'])} (held out: {s['held_out']})",
            f"residual: RMSE {a['rmse_mV']:.2f} mV, bias {a['bias_mV']:+.2f} mV, max {a['max_abs_mV']:.1f} mV, "
            f"s² {a['s2']:.3g}, decorrelation {a['decorrelation_s']:.0f} s, "
            f"{100 * a['slow_fraction']:.0f} % of its power below 1/600 Hz",
            f"score tests (threshold p < {s['threshold']['p_value']:.2g}; LM/dof, block variance):",
        ]
        untestable = untestable_causes(s)
        for row in s["ranking"]:
            mark = "*" if row["passes"] and row["cause"] not in untestable else " "
            lines.append(
                f" {mark} {row['cause']:<20} {row['score']:10.3g}  dof {row['dof']}  p {row['p_value']:.2g}"
                f"  ({100 * row['projected']:.0f} % not mimicked by the base"
                + (f"; close to {', '.join(row['mimicked_by'])})" if row["projected"] < 0.05 else ")")
                + ("  not testable here" if row["cause"] in untestable else "")
            )
        for a_, b_, c in s["indistinguishable"]:
            lines.append(f"   {a_} and {b_} are indistinguishable on these data (|cos| {c:.2f})")
        g = s["extension_gain"]
        if self.base_fit is not None:
            lines.append(f"held-out RMSE: the cell as given {g['rmse_cell_mV']:.2f} mV")
            lines.append(
                f"               base refit ({', '.join(self.base_fit.names)}): {self.base_fit.rmse_held_out_mV:.2f} mV"
            )
            for c in self.confirmations:
                lines.append(f"               with {c.cause}: {c.rmse_held_out_mV:.2f} mV")
        else:
            lines.append(f"held-out RMSE of the cell: {g['rmse_before_mV']:.2f} mV (no cause passed: nothing fitted)")
        cause = s["cause"]
        lines.append(f"cause: {cause} ({s['verdict']})" if cause else f"cause: none ({s['verdict']})")
        lines.append(f"verdict: {headline(s)[0]}")
        for c in s.get("cannot_tell", []):
            who = ", ".join(c.get("causes", [c["cause"]]))
            lines.append(f"cannot tell: {who}: {c['why']}; would tell: {c['kind']} profile, {c['experiment']}")
        for c in s.get("untestable", []):
            lines.append(
                f"not testable here: {c['cause']} ({c['why']}); would tell: {c['kind']} profile, {c['experiment']}"
            )
        for c in s.get("undetectable", []):
            label = "hidden, not ruled out" if "hidden_by" in c else "too small to see"
            lines.append(f"{label}: {c['cause']} ({c['why']}); would show: {c['kind']} profile, {c['experiment']}")
        for r in s.get("rounds", []):
            x = r["experiment"]
            lines.append(
                f"deciding experiment {r['round']} ({' vs '.join(r['causes'])}): profile {x['profile']} at "
                f"{x['ambient_degC']:.0f} degC, expected divergence chi2 {x['divergence']:.3g}, "
                f"{x['lab_hours']:.1f} lab h" + (f" -> cause {r.get('cause_after')}" if "cause_after" in r else "")
            )
        if s.get("undecided"):
            lines.append(f"undecided: {s['undecided']}")
        by_step = ", ".join(f"{k} {v:.0f} s" for k, v in s.get("seconds_by_step", {}).items())
        lines.append(f"({s['seconds']:.0f} s" + (f": {by_step})" if by_step else ")"))
        return "\n".join(lines)

    def write(self, outdir: str | Path) -> Path:
        """``summary.json``, the residual figures and ``report.html`` in ``outdir``; returns the page's path."""
        from battlab.diagnose import figures
        from battlab.report import html

        out = Path(outdir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.json").write_text(json.dumps(self.summary, indent=2, default=json_default))
        figs = [
            html.Figure(figures.residual_vs_time(self.analysis, out / "residual.png"), "measured − simulated"),
            html.Figure(
                figures.conditional_errors(self.analysis, out / "conditional.png"),
                "the error per bin of each feature (ordered by how much it depends on it)",
            ),
            html.Figure(figures.whiteness(self.analysis, out / "whiteness.png"), "autocorrelation and spectrum"),
        ]
        s = self.summary
        verdict, tone = headline(s)
        untestable = untestable_causes(s)
        rows = [
            [
                r["cause"],
                r["score"],
                r["dof"],
                r["p_value"],
                r["projected"],
                "not testable here" if r["cause"] in untestable else r["passes"],
            ]
            for r in s["ranking"]
        ]
        g = s["extension_gain"]
        conf_rows = []
        if self.base_fit is not None:
            b = self.base_fit
            conf_rows.append(["base model", ", ".join(b.names), b.rmse_train_mV, b.rmse_held_out_mV, b.converged])
        for c in self.confirmations:
            conf_rows.append([c.cause, ", ".join(c.names), c.rmse_train_mV, c.rmse_held_out_mV, c.converged])
        sections = [
            html.Section("Verdict", [html.Paragraph(verdict, tone), html.Paragraph(s["verdict"])]),
            html.Section("Residual", [html.KeyValues({k: v for k, v in s["residual"].items() if k != "features"})]),
            html.Section("Residual figures", figs),
            html.Section(
                "Score tests",
                [
                    html.Table(
                        ["cause", "LM/dof", "dof", "p-value", "not mimicked", "passes"],
                        rows,
                        caption="score tests at the extensions' off values, base directions projected out",
                        note=f"threshold: p < {s['threshold']['p_value']:.3g} ({s['threshold']['rule']})",
                    ),
                    *(
                        html.Paragraph(f"{a} and {b} are indistinguishable on these data (|cos| {c:.2f})")
                        for a, b, c in s["indistinguishable"]
                    ),
                ],
            ),
            html.Section(
                "Held-out confirmation",
                [
                    html.KeyValues(g),
                    html.Table(["model", "fitted", "training RMSE [mV]", "held-out RMSE [mV]", "converged"], conf_rows),
                ],
            ),
        ]
        undecided = [
            html.Paragraph(
                f"{'hidden, not ruled out' if 'hidden_by' in c else what}: {', '.join(c.get('causes', [c['cause']]))} "
                f"({c['why']}); would tell: {c['kind']} profile, {c['experiment']}"
            )
            for key, what in (
                ("cannot_tell", "cannot tell"),
                ("untestable", "not testable here"),
                ("undetectable", "too small to see"),
            )
            for c in s.get(key, [])
        ]
        if undecided:
            sections.insert(1, html.Section("What these data cannot tell", undecided))
        if s.get("rounds"):
            cols, rows_r = rounds_table(s["rounds"])
            sections.insert(1, html.Section("Deciding experiments", [html.Table(cols, rows_r)]))
        if self.warnings:
            sections.append(html.Section("Warnings", [html.Paragraph(w) for w in self.warnings]))
        return html.write(out / "report.html", f"Diagnosis of {self.cell_name}", sections, subtitle=verdict)
