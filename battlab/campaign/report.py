"""The campaign's report: one static page (``report.html``) with PNG figures, from the stages' summaries and files.

It opens with the answer (:func:`results_box`: the validation RMSE of each cell, whether the fits converged, s² and
how far their intervals can be trusted, whether every run completed); then the campaign's overview, then the section
each stage declares (:attr:`battlab.campaign.unit.Unit.report`: the functions below, each of a :class:`View`), the
run-log health and what was left out.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from battlab.report.html import Block, Figure, KeyValues, Paragraph, Section, Table, write


@dataclass(frozen=True)
class View:
    """What a stage's report section sees: the campaign directory, every stage's summary and files, the campaign,
    and where figures go."""

    directory: Path
    summaries: Mapping[str, Any]
    inputs: Mapping[str, Any]
    camp: Any
    fig_dir: Path

    def file(self, stage: str, role: str) -> Path | None:
        out = self.inputs.get(stage)
        if out is None or role not in out.files:
            return None
        return self.directory / out.files[role]


def _read(path: Path) -> Any:
    return json.loads(path.read_text())


def write_report(
    directory: Path, summaries: Mapping[str, Any], inputs: Mapping[str, Any], camp: Any, units: Sequence[Any]
) -> Path:
    """Write ``report.html`` (and its figures under ``figures/``) in ``directory``; returns its path."""
    from battlab.campaign.stages import STATE_FILE

    fig_dir = directory / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    view = View(directory, summaries, inputs, camp, fig_dir)
    state = _read(directory / STATE_FILE)["stages"] if (directory / STATE_FILE).exists() else {}
    health = health_rows(directory)
    S: list[Section] = [results_box(summaries, health), overview(view, state)]
    for u in units:
        if u.report is not None and u.name in summaries:
            out = u.report(view)
            S += out if isinstance(out, list) else [out] if out is not None else []
    S.append(health_section(health))
    skipped = list(camp.config.stages.skip)
    if skipped:
        S.append(Section("Left out", [Paragraph("stages left out by the configuration: " + ", ".join(skipped))]))
    cfg = camp.config
    return write(
        directory / "report.html",
        "battlab campaign",
        S,
        subtitle=f"{cfg.campaign.start} on {camp.tester.describe()['kind']}",
    )


def _fit_trust(f: Mapping[str, Any]) -> str:
    trust = f.get("trust", {})
    n_t, n_u = len(trust.get("trusted", [])), len(trust.get("untrusted", []))
    why = "; ".join(trust.get("caveats", []))
    return f"{n_t} of {n_t + n_u} trusted" + (f" ({why})" if why else "")


def results_box(summaries: Mapping[str, Any], health: list[list[Any]]) -> Section:
    """The answer first: validation RMSE per cell, each fit's convergence, s² and trusted intervals, run health.
    Green only when every fit converged to the noise (s² ≤ 2, a residual not correlated from sample to sample: no
    caveat on its intervals) and every run completed."""
    from battlab.identify.fit_summary import S2_MODEL_ERROR

    blocks: list[Block] = []
    fits = {k: summaries[k] for k in ("fit", "conventional") if k in summaries}
    aborted = [r for r in health if r[2] != "completed"]
    ok = bool(fits) and all(
        f.get("converged") and f.get("s2", np.inf) <= S2_MODEL_ERROR and not f.get("trust", {}).get("caveats")
        for f in fits.values()
    )
    ok = ok and not aborted
    if fits:
        rows = [
            [
                "OED" if k == "fit" else k,
                "yes" if f.get("converged") else "NO",
                f.get("s2"),
                _fit_trust(f),
            ]
            for k, f in fits.items()
        ]
        blocks.append(Table(["fit", "converged", "s²", "intervals"], rows, caption="identification"))
    v = summaries.get("validation")
    if v and v.get("rmse_mV"):
        labels = list(v["rmse_mV"])
        names = list(next(iter(v["rmse_mV"].values())))
        blocks.append(
            Table(
                ["validation test", *[f"{lab} [mV]" for lab in labels]],
                [[n, *[v["rmse_mV"][lab][n] for lab in labels]] for n in names],
                caption=f"validation RMSE against the {v['reference']}",
            )
        )
    if aborted:
        blocks.append(Paragraph(f"{len(aborted)} of {len(health)} runs did not complete: see Run-log health", "bad"))
    if fits:
        text = (
            "every fit converged to the noise (s² ≤ 2, a white residual), every run completed: the intervals can be "
            "trusted as marked"
            if ok
            else "read with care: a fit did not converge, its residual is model error (s² > 2, or correlated from "
            "sample to sample), or a run did not complete; the intervals marked untrusted say why"
        )
        blocks.insert(0, Paragraph(text, "good" if ok else "bad"))
    return Section("Results", blocks or [Paragraph("no fit in this campaign")])


def overview(view: View, state: Mapping[str, Any]) -> Section:
    camp, cfg = view.camp, view.camp.config
    lab_h = sum(float(v.get("lab_hours", 0.0)) for v in state.values())
    wall = sum(float(v.get("wall_s", 0.0)) for v in state.values())
    return Section(
        "Campaign",
        [
            KeyValues(
                {
                    "tester": camp.tester.describe()["kind"],
                    "hidden truth": camp.tester.truth if camp.tester.virtual else "unknown (real cell)",
                    "start cell": cfg.campaign.start,
                    "variant": "quick (reduced library, designs, repeats, fits)" if cfg.quick else "full",
                    "simulated lab hours" if camp.tester.virtual else "lab hours": round(lab_h, 2),
                    "wall time of the stages before the report [s]": round(wall, 1),
                }
            ),
            Table(
                ["stage", "wall time [s]", "lab hours"],
                [[k, v.get("wall_s"), v.get("lab_hours")] for k, v in state.items()],
                caption="stages (as last run)",
            ),
        ],
    )


def capacity(view: View) -> Section | None:
    """One section for both capacity checks (the 'after' stage draws it, with the 'before' one)."""
    from battlab.campaign import figures as figs
    from battlab.campaign.data import load as load_data

    caps = [(k, view.summaries[k]) for k in ("capacity_before", "capacity_after") if k in view.summaries]
    curves = {}
    for k, _ in caps:
        p = view.file(k, "log")
        if p is not None:
            d = load_data(p)
            m = d.columns["Step Index / 1"] == 3
            t, i = d.t[m], d.current[m]
            q = np.concatenate([[0.0], np.cumsum(-i[:-1] * np.diff(t))]) / 3600.0
            curves[k.replace("capacity_", "")] = (q, d.voltage[m])
    blocks: list[Block] = [
        Table(["check", "capacity [Ah]", "rated [Ah]"], [[k, s["capacity_Ah"], s["rated_Ah"]] for k, s in caps])
    ]
    if len(caps) == 2:
        fade = 100 * (1 - caps[1][1]["capacity_Ah"] / caps[0][1]["capacity_Ah"])
        blocks.append(Paragraph(f"capacity change over the campaign: {-fade:+.3f} %"))
    if curves:
        blocks.append(Figure(figs.capacity(curves, view.fig_dir / "capacity.png"), "C/3 discharge after CCCV"))
    return Section("Capacity before and after", blocks)


def capacity_before(view: View) -> Section | None:
    """Drawn with the 'after' check when the campaign has one."""
    return None if "capacity_after" in view.summaries else capacity(view)


def equilibrium(view: View) -> Section:
    e = view.summaries["equilibrium"]
    keys = ("method", "eps_s_n", "eps_s_p", "n_Li", "capacity_Ah", "rmse_mV", "rmse_5_95_mV", "rmse_all_mV")
    blocks: list[Block] = [KeyValues({k: e.get(k) for k in (*keys, "converged") if k in e})]
    if isinstance(e.get("truth"), dict) and all(isinstance(v, dict) for v in e["truth"].values()):
        rows = [
            [k, v["estimate"], v["ci95"], v["truth"], f"{100 * v['bias']:+.3f} %", v["covered"], v.get("trusted")]
            for k, v in e["truth"].items()
        ]
        blocks.append(Table(["parameter", "estimate", "95 % interval", "truth", "bias", "covered", "trusted"], rows))
    elif "truth" in e:
        blocks.append(KeyValues({f"truth {k}": v for k, v in e["truth"].items()}))
    if e.get("untrusted_because"):
        blocks.append(Paragraph("intervals not to be trusted: " + "; ".join(e["untrusted_because"]), "bad"))
    fp = view.file("equilibrium", "figure")
    if fp:
        blocks.append(Figure(fp, "OCV test (one C/20 cycle) and the fitted OCV"))
    return Section("Equilibrium (OCV test)", blocks)


def sweep(view: View) -> Section:
    s = view.summaries["sweep"]
    blocks: list[Block] = [KeyValues({k: s.get(k) for k in ("total", "ok", "flagged", "failed", "wall_seconds")})]
    fp = view.file("groups", "ranking_figure")
    if fp:
        blocks.append(Figure(fp, "orthogonalised sensitivity ranking (Fig. 4) and groups"))
    return Section("Sensitivity ranking", blocks)


def groups(view: View) -> Section:
    g = view.summaries["groups"]["groups"]
    return Section(
        "Parameter groups", [Table(["group", "parameters"], [[k + 1, ", ".join(x)] for k, x in enumerate(g)])]
    )


def noise(view: View) -> Section:
    n = view.summaries["noise"]
    rows = [[r["id"], r["direction"], r["intensity"], 1e6 * r["q_V"]] for r in n["runs"]]
    blocks: list[Block] = [
        Table(["profile", "direction", "Ĩ [A s^½]", "q [µV]"], rows, caption=f"{n['repeats']} trials each"),
        KeyValues({k: v for k, v in n["model"].items()}),
    ]
    fp = view.file("noise", "figure")
    if fp:
        blocks.append(Figure(fp, "noise model (eqs. 36-38) fitted to repeated trials"))
    return Section("Noise model", blocks)


def design(view: View) -> Section:
    from battlab.campaign import figures as figs

    d = view.summaries["design"]
    rows = [
        [k + 1, ", ".join(g["parameters"]), ", ".join(map(str, g["selected"])), g["logdet"]]
        for k, g in enumerate(d["groups"])
    ]
    blocks: list[Block] = [
        Table(["group", "parameters (cumulative)", "selected", "log det F"], rows, caption=f"{d['criterion']}-optimal")
    ]
    fp = view.file("design", "figure")
    if fp:
        blocks.append(Figure(fp, "design weights per group"))
    sel = d.get("selected_profiles", {})
    blocks.append(
        Table(
            ["profile", "kind", "start SOC", "duration [s]", "description"],
            [
                [pid, m.get("kind"), m.get("soc0"), m.get("duration"), (m.get("params") or {}).get("name")]
                for pid, m in sel.items()
            ],
            caption="selected inputs",
        )
    )
    try:
        from protocols.library import Library

        lib = Library.load(view.directory / view.inputs["library"].files["library"])
        items = [(f"profile {pid}", lib[int(pid)].t, lib[int(pid)].current) for pid in sel]
        blocks.append(Figure(figs.profiles(items, view.fig_dir / "selected_inputs.png"), "selected inputs: current"))
    except (KeyError, OSError):
        pass
    return Section("Optimal designs", blocks)


def parameters(view: View) -> Section:
    """The OED fit's estimates against start and truth, each interval marked trusted or not (and why), with the
    identifiable invariants; coverage counts only trusted intervals of interior parameters."""
    from battlab.campaign import figures as figs
    from battlab.cell import Cell

    f, camp = view.summaries["fit"], view.camp
    start = Cell.load(camp.config.campaign.start)
    conv = view.summaries.get("conventional", {}).get("parameters", {})
    rows, fig_rows = [], []
    rec = {r["parameter"]: r for r in f.get("recovery", [])}
    truth = Cell.load(camp.tester.truth) if camp.tester.virtual else None
    for name, p in f["parameters"].items():
        if name not in rec and truth is not None:
            continue  # the equilibrium parameters: their own section
        lo, hi = p["ci95"]
        r = rec.get(name)
        why = "; ".join(p.get("untrusted_because", []))
        rows.append(
            [
                name,
                float(start.value(name)),
                r["truth"] if r else None,
                p["value"],
                lo,
                hi,
                r["covered"] if r else None,
                "yes" if p.get("trusted") else "no",
                why,
            ]
        )
        tb = {
            "start": start.normalised(name),
            "estimate": p["theta_bar"],
            "truth": truth.normalised(name) if truth else None,
        }
        ci_bar = sorted([_norm(start, name, lo), _norm(start, name, hi)]) if lo is not None and hi is not None else None
        conv_bar = _norm(start, name, conv[name]["value"]) if name in conv else None
        fig_rows.append({"parameter": name, "theta_bar": tb, "ci_bar": ci_bar, "conv": conv_bar})
    for r in f.get("recovery_invariants", []):
        lo, hi = r["ci95"]
        why = "; ".join(r.get("untrusted_because", []))
        rows.append(
            [
                r["parameter"],
                r["start"],
                r["truth"],
                r["estimate"],
                lo,
                hi,
                r["covered"],
                "yes" if r.get("trusted") else "no",
                why,
            ]
        )
    cb = {r["parameter"]: r["conv"] for r in fig_rows if r["conv"] is not None}
    fig = figs.parameters(fig_rows, view.fig_dir / "parameters.png", cb)
    interior = [r for r in f.get("recovery", []) + f.get("recovery_invariants", []) if not r["truth_on_bound"]]
    trusted = [r for r in interior if r.get("trusted")]
    blocks: list[Block] = [
        Table(
            ["parameter", "start", "truth", "estimate", "95 % low", "95 % high", "covers truth", "trusted", "why not"],
            rows,
            caption="identified parameters and invariants (last cumulative stage)",
        ),
        Figure(fig, "estimates and 95 % intervals on the normalised axis, start (x), truth (*), conventional (◆)"),
        KeyValues({"converged": f["converged"], "s²": f["s2"], "data hours": f.get("data_hours")}),
    ]
    if interior:
        covered = sum(1 for r in trusted if r["covered"])
        blocks.append(
            Paragraph(
                f"trusted intervals: {len(trusted)} of {len(interior)} parameters and invariants whose truth is not on "
                f"a bound; {covered} of those {len(trusted)} cover the truth (an untrusted interval is not counted: "
                "set-identified, at a bound, unconverged or with s² > 2, its width says nothing)",
                "good" if trusted and covered >= 0.9 * len(trusted) else "bad",
            )
        )
    return Section("Identified parameters", blocks)


def _norm(cell: Any, name: str, value: float) -> float:
    return float(cell.with_values(**{name: value}).normalised(name))


def conventional(view: View) -> Section:
    c = view.summaries["conventional"]
    return Section(
        "Conventional baseline",
        [
            KeyValues(
                {
                    "test hours": c.get("test_hours"),
                    "fit converged": c.get("converged"),
                    "s²": c.get("s2"),
                    "intervals": _fit_trust(c),
                    "evaluations": sum(s["iterations"] for s in c.get("stages", [])),
                }
            ),
            Paragraph("all 18 parameters fitted at once, same start point, optimiser and stopping rule."),
        ],
    )


def validation(view: View) -> Section:
    v = view.summaries["validation"]
    labels = list(v["rmse_mV"])
    names = list(next(iter(v["rmse_mV"].values()))) if labels else []
    rows = [[n, *[v["rmse_mV"][lab][n] for lab in labels]] for n in names]
    blocks: list[Block] = [
        Table(
            ["validation test", *[f"{lab} [mV]" for lab in labels]], rows, caption=f"RMSE against the {v['reference']}"
        )
    ]
    for n, fig in v.get("figures", {}).items():
        blocks.append(Figure(view.directory / "validation" / fig, n))
    return Section("Validation", blocks)


def diagnosis(view: View) -> Section:
    """What the fitted cell still misses: the residual before, the cause named (or what cannot be told apart), the
    deciding experiments run, and the residual after the extend step on every held-out validation test."""
    dg = view.summaries["diagnosis"]
    cause = dg.get("cause")
    blocks: list[Block] = [
        Paragraph(
            f"cause: {cause} ({dg.get('how') or 'extension'})" if cause else "no cause named",
            "bad" if cause else ("good" if dg.get("residual_over_noise", 0) < 10 else "bad"),
        ),
        Paragraph(dg.get("verdict", "")),
        Paragraph(dg.get("method", ""), ""),
    ]
    for c in dg.get("cannot_tell", []):
        blocks.append(Paragraph(f"cannot tell {', '.join(c.get('causes', [c['cause']]))}: {c['experiment']}"))
    if dg.get("rounds"):
        from battlab.diagnose.report import rounds_table

        cols, rows = rounds_table(dg["rounds"])
        blocks.append(Table(cols, rows, caption="deciding experiments run on the tester"))
    if dg.get("undecided"):
        blocks.append(Paragraph(f"undecided: {dg['undecided']}", "warn"))
    tried = dg.get("extended") or []
    if len(tried) > 1:
        blocks.append(
            Table(
                ["cause", "OED cell [mV]", "base refit [mV]", "extended [mV]", "kept"],
                [
                    [t["cause"], t.get("rmse_oed_mV", t["rmse_before_mV"]), t.get("rmse_refit_mV"), t["rmse_after_mV"]]
                    + ["yes" if t["kept"] else "no"]
                    for t in tried
                ],
                caption="causes extended (extend step) and scored on the validation tests (mean RMSE), beside the OED "
                "cell and its base refitted alone by the same evaluations (the control)",
            )
        )
    eqs = dg.get("equilibrium_refit") or {}
    if eqs:
        blocks.append(
            Table(
                ["refitted with", "OCV test RMSE [mV]", "converged", "capacity [Ah]", "its parameters [95 % interval]"],
                [
                    [
                        k if k != "control" else "the base alone (control)",
                        e["rmse_mV"],
                        "yes" if e["converged"] else "no",
                        e["capacity_Ah"],
                        "; ".join(
                            f"{n} {v:.4g}" + (f" [{lo:.4g}, {hi:.4g}]" if lo is not None else "")
                            for n, (v, lo, hi) in e["fitted"].items()
                        ),
                    ]
                    for k, e in eqs.items()
                ],
                caption="the equilibrium refitted from the OCV test for a cause that changes what the slow cycle "
                "measures, its parameters beside the electrodes' moles (the extend step starts from it)",
            )
        )
    table = dg.get("validation_rmse_mV") or {}
    if table:
        names = list(next(iter(table.values())))
        shown = (dg.get("extension_gain") or {}).get("cause") or cause or dg.get("suggested")
        control, off = "refit" in table, "extension off" in table
        blocks.append(
            Table(
                [
                    "held-out test",
                    "before [mV]",
                    *(["base refit [mV]"] if control else []),
                    "after [mV]",
                    *(["after, extension off [mV]"] if off else []),
                ],
                [
                    [
                        n,
                        table["before"][n],
                        *([table["refit"][n]] if control else []),
                        table["after"][n],
                        *([table["extension off"][n]] if off else []),
                    ]
                    for n in names
                ],
                caption=f"the OED fit before and after the {shown} extension (extend step)"
                + (", beside its base refitted alone by the same evaluations" if control else "")
                + (", and the extended cell with the extension switched off (the cause's own part)" if off else ""),
            )
        )
    g = dg.get("diagnosis_gain") or {}
    if g:
        blocks.append(KeyValues({k: v for k, v in g.items() if not isinstance(v, dict)}))
    page = view.file("diagnosis", "report")
    if page is not None:
        blocks.append(Paragraph(f"the diagnosis's own report: {page.relative_to(view.directory)}"))
    return Section("Diagnosis", blocks)


def export(view: View) -> Section:
    return Section("Export", [KeyValues(view.summaries["export"])])


def health_rows(directory: Path) -> list[list[Any]]:
    rows = []
    for p in sorted((directory / "health").glob("*.json")):
        for r in _read(p):
            rows.append(
                [
                    p.stem,
                    r["log"],
                    r["status"],
                    r["samples"],
                    r["late_samples"],
                    r["gaps"],
                    r["max_gap_s"],
                    "; ".join(r["safety_events"]),
                ]
            )
    return rows


def health_section(rows: list[list[Any]]) -> Section:
    """Every run's log: late samples, gaps, how it ended. Green only when every run completed without a gap."""
    if not rows:
        return Section("Run-log health", [Paragraph("no runs in this campaign directory")])
    late = sum(r[4] for r in rows)
    gaps = sum(r[5] for r in rows)
    ended = [r for r in rows if r[2] != "completed"]
    text = f"{len(rows)} runs, {sum(r[3] for r in rows)} samples, {late} late, {gaps} gaps (missed samples)"
    if ended:
        text += f"; {len(ended)} did not complete (" + ", ".join(f"{r[1]}: {r[2]}" for r in ended[:5]) + ")"
    tone = "good" if late == 0 and gaps == 0 and not ended else "bad"
    return Section(
        "Run-log health",
        [
            Paragraph(text, tone),
            Table(["stage", "log", "status", "samples", "late", "gaps", "max gap [s]", "safety events"], rows),
        ],
    )
