"""The campaign's report: one static page (``report.html``) with PNG figures, from the stages' summaries and files.

Sections follow the campaign: capacity before and after, equilibrium, sensitivity ranking and groups, noise model,
designs and the selected inputs, identified parameters with intervals (normalised axis, against start and truth),
the conventional baseline, validation, diagnosis, run-log health, export. A stage left out is said so.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from battlab.report.html import Figure, KeyValues, Paragraph, Section, Table, write


def _read(path: Path) -> Any:
    return json.loads(path.read_text())


def _f(directory: Path, inputs: Mapping[str, Any], stage: str, role: str) -> Path | None:
    out = inputs.get(stage)
    if out is None or role not in out.files:
        return None
    return directory / out.files[role]


def write_report(directory: Path, summaries: Mapping[str, Any], inputs: Mapping[str, Any], camp: Any) -> Path:
    """Write ``report.html`` (and its figures under ``figures/``) in ``directory``; returns its path."""
    from battlab.campaign import figures as figs
    from battlab.campaign.stages import STATE_FILE

    fig_dir = directory / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    state = _read(directory / STATE_FILE)["stages"] if (directory / STATE_FILE).exists() else {}
    S: list[Section] = []
    cfg = camp.config
    lab_h = sum(float(v.get("lab_hours", 0.0)) for v in state.values())
    wall = sum(float(v.get("wall_s", 0.0)) for v in state.values())
    S.append(
        Section(
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
    )
    # capacity
    caps = [(k, summaries[k]) for k in ("capacity_before", "capacity_after") if k in summaries]
    if caps:
        from battlab.campaign.data import load as load_data

        curves = {}
        for k, _ in caps:
            p = _f(directory, inputs, k, "log")
            if p is not None:
                d = load_data(p)
                m = d.columns["Step Index / 1"] == 3
                t, i = d.t[m], d.current[m]
                q = np.concatenate([[0.0], np.cumsum(-i[:-1] * np.diff(t))]) / 3600.0
                curves[k.replace("capacity_", "")] = (q, d.voltage[m])
        blocks: list[Any] = [
            Table(["check", "capacity [Ah]", "rated [Ah]"], [[k, s["capacity_Ah"], s["rated_Ah"]] for k, s in caps])
        ]
        if len(caps) == 2:
            fade = 100 * (1 - caps[1][1]["capacity_Ah"] / caps[0][1]["capacity_Ah"])
            blocks.append(Paragraph(f"capacity change over the campaign: {-fade:+.3f} %"))
        if curves:
            blocks.append(Figure(figs.capacity(curves, fig_dir / "capacity.png"), "C/3 discharge after CCCV"))
        S.append(Section("Capacity before and after", blocks))
    if "equilibrium" in summaries:
        e = summaries["equilibrium"]
        keys = ("method", "eps_s_n", "eps_s_p", "n_Li", "capacity_Ah", "rmse_mV", "rmse_all_mV", "converged")
        blocks = [KeyValues({k: e.get(k) for k in keys if k in e})]
        if isinstance(e.get("truth"), dict) and all(isinstance(v, dict) for v in e["truth"].values()):
            rows = [
                [k, v["estimate"], v["ci95"], v["truth"], f"{100 * v['bias']:+.3f} %", v["covered"]]
                for k, v in e["truth"].items()
            ]
            blocks.append(Table(["parameter", "estimate", "95 % interval", "truth", "bias", "covered"], rows))
        elif "truth" in e:
            blocks.append(KeyValues({f"truth {k}": v for k, v in e["truth"].items()}))
        fp = _f(directory, inputs, "equilibrium", "figure")
        if fp:
            blocks.append(Figure(fp, "OCV test (one C/20 cycle) and the fitted OCV"))
        S.append(Section("Equilibrium (OCV test)", blocks))
    if "sweep" in summaries:
        s = summaries["sweep"]
        blocks = [KeyValues({k: s.get(k) for k in ("total", "ok", "flagged", "failed", "wall_seconds")})]
        fp = _f(directory, inputs, "groups", "ranking_figure")
        if fp:
            blocks.append(Figure(fp, "orthogonalised sensitivity ranking (Fig. 4) and groups"))
        S.append(Section("Sensitivity ranking", blocks))
    if "groups" in summaries:
        g = summaries["groups"]["groups"]
        S.append(
            Section(
                "Parameter groups",
                [Table(["group", "parameters"], [[k + 1, ", ".join(x)] for k, x in enumerate(g)])],
            )
        )
    if "noise" in summaries:
        n = summaries["noise"]
        rows = [[r["id"], r["direction"], r["intensity"], 1e6 * r["q_V"]] for r in n["runs"]]
        blocks = [
            Table(["profile", "direction", "Ĩ [A s^½]", "q [µV]"], rows, caption=f"{n['repeats']} trials each"),
            KeyValues({k: v for k, v in n["model"].items()}),
        ]
        fp = _f(directory, inputs, "noise", "figure")
        if fp:
            blocks.append(Figure(fp, "noise model (eqs. 36-38) fitted to repeated trials"))
        S.append(Section("Noise model", blocks))
    if "design" in summaries:
        d = summaries["design"]
        rows = [
            [k + 1, ", ".join(g["parameters"]), ", ".join(map(str, g["selected"])), g["logdet"]]
            for k, g in enumerate(d["groups"])
        ]
        blocks = [
            Table(
                ["group", "parameters (cumulative)", "selected", "log det F"], rows, caption=f"{d['criterion']}-optimal"
            )
        ]
        fp = _f(directory, inputs, "design", "figure")
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

            lib = Library.load(directory / inputs["library"].files["library"])
            items = [(f"profile {pid}", lib[int(pid)].t, lib[int(pid)].current) for pid in sel]
            blocks.append(Figure(figs.profiles(items, fig_dir / "selected_inputs.png"), "selected inputs: current"))
        except (KeyError, OSError):
            pass
        S.append(Section("Optimal designs", blocks))
    if "fit" in summaries:
        S.append(_parameters(summaries, fig_dir, camp))
    if "conventional" in summaries:
        c = summaries["conventional"]
        S.append(
            Section(
                "Conventional baseline",
                [
                    KeyValues(
                        {
                            "test hours": c.get("test_hours"),
                            "fit converged": c.get("converged"),
                            "s²": c.get("s2"),
                            "evaluations": sum(s["iterations"] for s in c.get("stages", [])),
                        }
                    ),
                    Paragraph("all 18 parameters fitted at once, same start point, optimiser and stopping rule."),
                ],
            )
        )
    if "validation" in summaries:
        v = summaries["validation"]
        labels = list(v["rmse_mV"])
        names = list(next(iter(v["rmse_mV"].values()))) if labels else []
        rows = [[n, *[v["rmse_mV"][lab][n] for lab in labels]] for n in names]
        blocks = [
            Table(
                ["validation test", *[f"{lab} [mV]" for lab in labels]],
                rows,
                caption=f"RMSE against the {v['reference']}",
            )
        ]
        for n, f in v.get("figures", {}).items():
            blocks.append(Figure(directory / "validation" / f, n))
        S.append(Section("Validation", blocks))
    if "diagnosis" in summaries:
        dg = summaries["diagnosis"]
        blocks = [Paragraph(dg["method"])]
        if dg.get("name_a_cause"):
            blocks.append(Paragraph(f"To name a cause, in the campaign directory: {dg['name_a_cause']}"))
        for n, a in dg["data"].items():
            blocks.append(
                KeyValues(
                    {
                        f"{n}: {k}": a.get(k)
                        for k in ("rmse_mV", "bias_mV", "s2", "ljung_box_p", "slow_power_share")
                        if k in a
                    }
                )
            )
        blocks += [Figure(directory / "diagnosis" / f, f) for f in dg.get("figures", [])[:4]]
        S.append(Section("Diagnosis", blocks))
    S.append(_health(directory))
    if "export" in summaries:
        S.append(Section("Export", [KeyValues(summaries["export"])]))
    skipped = [s for s in cfg.stages.skip]
    if skipped:
        S.append(Section("Left out", [Paragraph("stages left out by the configuration: " + ", ".join(skipped))]))
    return write(
        directory / "report.html",
        "battlab campaign",
        S,
        subtitle=f"{cfg.campaign.start} on {camp.tester.describe()['kind']}",
    )


def _parameters(summaries: Mapping[str, Any], fig_dir: Path, camp: Any) -> Section:
    from battlab.campaign import figures as figs
    from battlab.cell import Cell

    f = summaries["fit"]
    start = Cell.load(camp.config.campaign.start)
    conv = summaries.get("conventional", {}).get("parameters", {})
    rows, fig_rows = [], []
    rec = {r["parameter"]: r for r in f.get("recovery", [])}
    truth = Cell.load(camp.tester.truth) if camp.tester.virtual else None
    for name, p in f["parameters"].items():
        lo, hi = p["ci95"]
        r = rec.get(name)
        rows.append(
            [
                name,
                float(start[name]),
                r["truth"] if r else None,
                p["value"],
                lo,
                hi,
                r["covered"] if r else None,
                p["bound"] or "",
            ]
        )
        tb = {
            "start": start.normalised(name),
            "estimate": p["theta_bar"],
            "truth": truth.normalised(name) if truth else None,
        }
        ci_bar = None
        if lo is not None and hi is not None:
            ci_bar = sorted([_norm(start, name, lo), _norm(start, name, hi)])
        conv_bar = _norm(start, name, conv[name]["value"]) if name in conv else None
        fig_rows.append({"parameter": name, "theta_bar": tb, "ci_bar": ci_bar, "conv": conv_bar})
    cb = {r["parameter"]: r["conv"] for r in fig_rows if r["conv"] is not None}
    fig = figs.parameters(fig_rows, fig_dir / "parameters.png", cb)
    interior = [r for r in f.get("recovery", []) if not r["truth_on_bound"]]
    covered = sum(1 for r in interior if r["covered"])
    blocks: list[Any] = [
        Table(
            ["parameter", "start", "truth", "estimate", "95 % low", "95 % high", "covers truth", "at bound"],
            rows,
            caption="identified parameters (last cumulative stage)",
        ),
        Figure(fig, "estimates and 95 % intervals on the normalised axis, start (x), truth (*), conventional (◆)"),
        KeyValues({"converged": f["converged"], "s²": f["s2"], "data hours": f.get("data_hours")}),
    ]
    if interior:
        informative = sum(1 for r in fig_rows if r["ci_bar"] is not None and r["ci_bar"][1] - r["ci_bar"][0] < 0.5)
        blocks.append(
            Paragraph(
                f"coverage: {covered} of {len(interior)} parameters whose truth is not on a bound; "
                f"{informative} of {len(fig_rows)} intervals span less than half their parameter's range "
                "(an interval as wide as the bounds covers the truth without saying anything)"
            )
        )
    return Section("Identified parameters", blocks)


def _norm(cell: Any, name: str, value: float) -> float:
    return float(cell.with_values(**{name: value}).normalised(name))


def _health(directory: Path) -> Section:
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
    if not rows:
        return Section("Run-log health", [Paragraph("no runs in this campaign directory")])
    late = sum(r[4] for r in rows)
    gaps = sum(r[5] for r in rows)
    tone = "good" if late == 0 and gaps == 0 else "bad"
    return Section(
        "Run-log health",
        [
            Paragraph(
                f"{len(rows)} runs, {sum(r[3] for r in rows)} samples, {late} late, {gaps} gaps (missed samples)", tone
            ),
            Table(["stage", "log", "status", "samples", "late", "gaps", "max gap [s]", "safety events"], rows),
        ],
    )
