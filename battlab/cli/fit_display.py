"""What ``battlab fit`` shows while it works and when it is done: a subscriber of the fit's progress events that
prints each finished step (the equilibrium fit; per stage, each data file's RMSE before → after against its noise
level, how the stage ended and what to do when it stopped at its limit), a live bar inside a stage on a terminal,
and at the end the estimates with their units and how far each interval can be trusted."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import click

from battlab.identify.fit_report import EquilibriumDone, StageDone, ValuesDone
from battlab.progress import ProgressEvent, RichBar


class FitDisplay:
    """Renders the fit's events (:mod:`battlab.progress`); stage figures go to ``<stem>.stageK.*.png``."""

    def __init__(self, out: Path, stem: str, *, bar: bool = True) -> None:
        self.out, self.stem = out, stem
        self.bar = RichBar() if bar and click.get_text_stream("stderr").isatty() else None
        self.done = 0  # stages finished
        self.equilibrium_written = False

    def __call__(self, ev: ProgressEvent) -> None:
        if ev.kind in ("start", "advance", "stop", "failed") and self.bar is not None:
            self.bar(ev)
        if ev.kind != "note":
            return
        p = ev.payload
        if isinstance(p, EquilibriumDone):
            self.equilibrium_written = True
            self.equilibrium(p.data, p.result)
        elif isinstance(p, StageDone):
            self.done = p.stage
            self.stage(p.stage, p.total, p.result)
        elif isinstance(p, ValuesDone):
            self.values(p.result)
        elif ev.text:
            click.echo(ev.text, err=ev.text.startswith("warning"))

    def equilibrium(self, name: str, eq: Any) -> None:
        click.echo(
            f"equilibrium ({name}): capacity {eq.capacity:.4f} Ah, eps_s_n {eq.eps_s_n:.4f}, "
            f"eps_s_p {eq.eps_s_p:.4f}, n_Li {eq.n_Li:.5f} mol, RMSE {eq.rmse_mV:.1f} mV "
            f"({eq.rmse_5_95_mV:.1f} mV over 5-95 % SOC)"
        )

    def stage(self, k: int, total: int, r: Any) -> None:
        from battlab.identify.workflow import stage_figures

        c = r.convergence
        # the reason starts with its own "converged" / "not converged": said once, in capitals when it did not
        why = c.reason.removeprefix("not converged").removeprefix("converged").lstrip(":; ")
        sep = " " if why.startswith("(") else ": " if why else ""
        click.echo(
            f"stage {k} of {total}: {len(r.names)} parameters, {c.iterations} evaluations, "
            f"{'converged' if c.converged else 'NOT converged'}{sep}{why}"
        )
        width = max((len(n) for n in r.rmse_mV), default=4)
        click.echo(f"  {'data':<{width}}  RMSE before -> after [mV]  noise [mV]  after/noise")
        for name, after in r.rmse_mV.items():
            before = r.rmse_before_mV.get(name, float("nan"))
            noise = r.noise_mV.get(name, float("nan"))
            click.echo(f"  {name:<{width}}  {before:11.2f} -> {after:<10.2f}  {noise:10.3f}  {after / noise:11.3g}")
        if not c.converged and c.reason.startswith("not converged: maximum number"):
            click.echo(
                f"  stage {k} stopped at its limit of {c.iterations} evaluations: give more (--max-iter "
                f"{2 * c.iterations}), or start again from the written cell (--cell {self.out}); its intervals are "
                "not to be trusted until it converges",
                err=True,
            )
        stage_figures(r, self.out.with_name(f"{self.stem}.stage{k}"))

    def values(self, vf: Any) -> None:
        if hasattr(vf, "energies"):  # the Arrhenius refits
            click.echo(
                "activation energies [kJ/mol]: "
                + ", ".join(f"{k} {vf.start[k] / 1e3:.1f} -> {v / 1e3:.1f}" for k, v in vf.energies.items())
                + (f" (clipped: {', '.join(vf.clipped)})" if vf.clipped else "")
            )
            for amb, vals in vf.values.items():
                click.echo(f"  at {amb - 273.15:.1f} degC: " + ", ".join(f"{k} {v:.4g}" for k, v in vals.items()))
            after = vf.rmse_after_mV
            refits = [f"{k} {v:.1f} -> {after.get(k, float('nan')):.1f}" for k, v in vf.rmse_before_mV.items()]
            if refits:  # a refit that stays far from its data gives a per-temperature value not worth a slope
                click.echo("  refits' RMSE [mV]: " + ", ".join(refits))
            return
        unit = "mV" if vf.target == "voltage" else "K"
        before = ", ".join(f"{k} {v:.2f}" for k, v in vf.rmse_before.items())
        after = ", ".join(f"{k} {v:.2f}" for k, v in vf.rmse_after.items())
        click.echo(
            f"value fit ({vf.target}; {vf.evaluations} evaluations, {vf.seconds:.0f} s): "
            + ", ".join(f"{k} {vf.start[k]:.4g} -> {v:.4g}" for k, v in vf.values.items())
            + f"; RMSE [{unit}] {before} -> {after}"
        )


def print_estimates(r: Any, summary: dict[str, Any]) -> None:
    """The final stage's estimates: value and unit, 95 % interval, and whether it can be trusted. A row's note gives
    its own reasons (a bound, set-identified, ...); what holds for every interval of the fit (not converged, s², a
    correlated residual) is said once under the table, not on every row."""
    from rich.table import Table

    from battlab import parameters
    from battlab.cli.console import make_console

    caveats = list(summary.get("trust", {}).get("caveats", []))
    t = Table(
        title=f"identified parameters (stage {r.stage}; s² = {r.statistics.s2:.3g})",
        caption=("every interval above: " + "; ".join(caveats)) if caveats else None,
        caption_justify="left",
    )
    for col in ("parameter", "value", "unit", "95 % interval", "trusted", "note"):
        t.add_column(col)
    entries = summary.get("parameters", {})
    for e in r.statistics.estimates:
        ci = f"[{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]" if e.ci95 else "-"
        entry = entries.get(e.name, {})
        why = "; ".join(own_reasons(entry, caveats))
        t.add_row(e.name, f"{e.value:.4g}", parameters.spec(e.name).unit, ci, _yes(entry.get("trusted")), why)
    inv = summary.get("invariants", {})
    for i in r.statistics.invariants:
        entry = inv.get(i.name, {})
        note = "; ".join([f"invariant {i.definition}", *own_reasons(entry, caveats)])
        t.add_row(i.name, f"{i.value:.4g}", "", f"[{i.ci95[0]:.4g}, {i.ci95[1]:.4g}]", _yes(entry.get("trusted")), note)
    make_console().print(t)


def own_reasons(entry: dict[str, Any], caveats: Sequence[str]) -> list[str]:
    """Why this interval cannot be trusted, less the fit's ``caveats`` (said once for all rows)."""
    return [w for w in entry.get("untrusted_because", []) if w not in caveats]


def _yes(flag: bool | None) -> str:
    return "-" if flag is None else ("yes" if flag else "NO")


def verdict(summary: dict[str, Any]) -> str:
    """The fit's answer in one line a bench engineer reads first: how well the cell explains each data file
    against its noise, and how far the intervals can be trusted."""
    rmse = summary.get("rmse_mV", {})
    last = (summary.get("stages") or [{}])[-1]
    noise = last.get("noise_mV", {})
    parts = [f"{n} {v:.2f} mV" + (f" ({v / noise[n]:.3g} x noise)" if noise.get(n) else "") for n, v in rmse.items()]
    trust = summary.get("trust", {})
    n_t, n_u = len(trust.get("trusted", [])), len(trust.get("untrusted", []))
    caveat = "; ".join(trust.get("caveats", []))
    how = f"{n_t} of {n_t + n_u} intervals trusted" + (f" ({caveat})" if caveat else "")
    state = "converged" if summary.get("converged") else "NOT converged"
    return f"fit {state}: RMSE " + ", ".join(parts) + f"; {how}"
