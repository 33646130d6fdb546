"""The full campaign's identification on several seeds of the virtual lab: does the loop recover its own truth?

A base campaign directory (``battlab campaign -o BASE``, the full campaign) provides what the seeds share: the input
library, the sensitivity sweep, the groups, the noise model and the designs. Per seed (a fresh virtual cell
``nca18650-true`` with noise seed s) the lab stages run again through the campaign's own stage functions: the OCV
test and the equilibrium fit, the designed experiments (with their replacements), the cumulative OED fit, and the
validation tests (0.5C and 1C discharges from full, US06 from SOC 0.8); ``--conventional`` adds the conventional
baseline. Printed per seed, then over the seeds:

- the equilibrium: estimates of ε_s⁻, ε_s⁺, n_Li and the capacity, their bias against the truth and whether the
  95 % intervals cover it;
- the designed experiments: completed, replaced, lost to a safety limit;
- the OED fit: convergence per stage, s² on its own data (target ≤ 2), its time;
- validation RMSE [mV] against the noise-free truth per profile (target ≤ 1 mV for the OED fit);
- coverage of the truth by the 95 % intervals per parameter (the 12 whose truth lies inside the bounds) and per
  invariant τ, κ, ρ (target: ≥ 90 % over the seeds).

``--fit lead-in`` fits with each experiment's preparation as lead-in and a start-SOC nuisance per experiment
(:func:`battlab.campaign.data.experiment_after_preparation`, ``battlab.identify.fit.fit(soc_span=…)``) instead of
the campaign's fit stage; ``--fit campaign`` (default) runs the campaign's stage as it is.

    PYTHONPATH=$PWD python benchmarks/bench_campaign_scale.py BASE --seeds 5 [--fit lead-in] [--json out.json]

Timing: on a quiet 2-core machine a seed takes about the campaign's lab stages (OCV, experiments, validation: a few
minutes of virtual-tester time) plus the fit (the longest part); state the load (``uptime``) with the numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

S2_TARGET = 2.0
RMSE_TARGET_MV = 1.0
COVERAGE_TARGET = 0.9


def shared_inputs(base: Path) -> dict[str, Any]:
    """The base campaign's stage outputs the seeds share, with absolute file paths."""
    from battlab.campaign.stages import StageOutput

    state = json.loads((base / "campaign.json").read_text())["stages"]
    out = {}
    for name in ("library", "sweep", "groups", "noise", "design"):
        if name not in state:
            raise SystemExit(f"{base}: the base campaign has no finished stage {name!r} (run the full campaign first)")
        rec = state[name]
        files = {k: str((base / v).resolve()) for k, v in rec["files"].items()}
        out[name] = StageOutput(files, rec["summary"], rec.get("lab_hours", 0.0))
    return out


def fit_lead_in(camp: Any, ctx: Any, directory: Path) -> dict[str, Any]:
    """The cumulative OED fit with the preparations as lead-in and a start-SOC nuisance per experiment."""
    from battlab.campaign import data as D
    from battlab.campaign.identify import recovery
    from battlab.cell import Cell
    from battlab.identify import fit as F
    from battlab.identify.forward import ForwardModel
    from battlab.noise import NoiseModel

    cell = Cell.load(str(ctx.path("equilibrium", "cell")))
    model = NoiseModel(**json.loads(Path(ctx.path("noise", "model")).read_text())["model"])
    ex = ctx.inputs["experiments"]
    replaced = ex.summary.get("replaced", {})
    exps = {}
    for key, rel in ex.files.items():
        if key.startswith("log_"):
            pid = key.removeprefix("log_")
            log = directory / rel
            prep = log.with_name(f"{log.stem}_prep.h5")
            exps[pid] = D.experiment_after_preparation(prep, log, cell, name=f"profile {pid}", noise=model)
    fm = ForwardModel(cell, v_margin=0.15)
    opts = F.Options(max_nfev=camp.config.fit.max_evaluations, polish=camp.config.fit.polish)
    names: list[str] = []
    used: list[str] = []
    current, res, stages = cell, None, []
    for k, g in enumerate(ctx.inputs["design"].summary["groups"], start=1):
        names += [n for n in g["parameters"] if n not in names]
        sel = [str(replaced.get(str(p), p)) for p in g["selected"]]
        used += [p for p in sel if p in exps and p not in used]
        es = [exps[p] for p in used]
        res = F.fit(cell, es, names, options=opts, forward=fm, start=current, stage=k, soc_span=0.01)
        current = res.cell
        for e in es:  # the next stage starts from the fitted start SOCs
            exps[e.name.removeprefix("profile ")] = replace(e, soc0=res.extra["soc0"][e.name])
        c = res.convergence
        stages.append({"iterations": c.iterations, "converged": c.converged, "reason": c.reason, "seconds": c.seconds})
    assert res is not None
    st = res.statistics
    out = directory / "fit" / "oed.bpx.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    res.cell.renamed("oed").to_bpx(out)
    return {
        "cell": str(out),
        "s2": st.s2,
        "converged": all(s["converged"] for s in stages),
        "stages": stages,
        "rmse_mV": res.rmse_mV,
        "recovery": recovery(st.estimates, Cell.load(camp.tester.truth), cell),
        "invariants": {i.name: {"value": i.value, "ci95": list(i.ci95)} for i in st.invariants},
    }


def validate(camp: Any, ctx: Any, cells: dict[str, Any]) -> dict[str, dict[str, float]]:
    """The campaign's validation tests on the seed's cell, each fitted cell scored against the noise-free truth."""
    from battlab.campaign import plans as P
    from battlab.campaign.assessment import CC_DT, VALIDATION_CC, VALIDATION_DRIVE_ID
    from battlab.campaign.identify import score
    from battlab.cell import Cell
    from protocols.library import Library

    cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]
    lib = Library.load(ctx.path("library", "library"))
    logs, notes = {}, {}
    for c in VALIDATION_CC:
        camp.run(P.prepare(1.0, camp.q_rated, cap, camp.ambient), f"validation/cc_{c:g}C_prep")
        out = camp.run_to_limit(
            P.constant_current(-c, camp.q_rated, camp.ambient, rest_after_s=camp.rest_after_s),
            f"validation/cc_{c:g}C",
            notes,
        )
        logs[f"{c:g}C discharge"] = (out.log_path, CC_DT)
    prof = lib[VALIDATION_DRIVE_ID]
    camp.run(P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient), "validation/drive_prep")
    out = camp.run(camp.measurement(prof), "validation/drive")
    logs[f"US06 from SOC {prof.soc0:g}"] = (out.log_path, 1.0)
    return score(logs, cells, Cell.load(camp.tester.truth), camp.directory / "validation")["rmse_mV"]


def coverage_of(fit: dict[str, Any], truth: Any) -> dict[str, bool | None]:
    """Per parameter (truth inside its bounds) and invariant: does the 95 % interval hold the truth?"""
    from battlab.identify.symmetry import INVARIANTS

    out: dict[str, bool | None] = {}
    for r in fit["recovery"]:
        if not r["truth_on_bound"]:
            out[r["parameter"]] = bool(r["covered"])
    for name, v in fit["invariants"].items():
        powers = next(p[name] for p in INVARIANTS.values() if name in p)
        t = float(np.prod([float(truth[n]) ** a for n, a in powers.items()]))
        lo, hi = v["ci95"]
        out[name] = None if lo is None else bool(lo <= t <= hi)
    return out


def run_seed(base: Path, seed: int, work: Path, shared: dict[str, Any], how: str, conventional: bool) -> dict[str, Any]:
    from battlab.campaign import assessment, characterisation, experiment_design
    from battlab.campaign.config import CampaignConfig
    from battlab.campaign.context import Campaign
    from battlab.campaign.stages import StageContext, StageOutput
    from battlab.campaign.tester import Tester
    from battlab.cell import Cell

    directory = work / f"seed{seed}"
    directory.mkdir(parents=True, exist_ok=True)
    camp = Campaign(CampaignConfig(), Tester(seed=seed), directory)
    truth = Cell.load(camp.tester.truth)
    outputs: dict[str, StageOutput] = dict(shared)
    times: dict[str, float] = {}

    def stage(name: str, fn: Any) -> StageOutput:
        t0 = time.perf_counter()
        out = fn(camp)(StageContext(directory, outputs, lambda d, n, text: None))
        times[name] = time.perf_counter() - t0
        outputs[name] = out
        return out

    stage("ocv", characterisation.ocv)
    eq = stage("equilibrium", characterisation.equilibrium).summary
    ex = stage("experiments", experiment_design.experiments).summary
    t0 = time.perf_counter()
    ctx = StageContext(directory, outputs, lambda d, n, text: None)
    if how == "lead-in":
        fit = fit_lead_in(camp, ctx, directory)
    else:
        fit = dict(assessment.fit_oed(camp)(ctx).summary)
        fit["cell"] = str(directory / "fit" / "oed.bpx.json")
    times["fit"] = time.perf_counter() - t0
    cells = {"nominal": Cell.load(str(ctx.path("equilibrium", "cell"))), "OED": Cell.load(fit["cell"])}
    if conventional:
        conv = stage("conventional", assessment.conventional)
        cells["conventional"] = Cell.load(str(directory / conv.files["cell"]))
    t0 = time.perf_counter()
    rmse = validate(camp, StageContext(directory, outputs, lambda d, n, text: None), cells)
    times["validation"] = time.perf_counter() - t0
    return {
        "seed": seed,
        "equilibrium": eq.get("truth"),
        "equilibrium_converged": eq.get("converged"),
        "experiments": {k: ex.get(k) for k in ("completed", "replaced", "lost", "failed")},
        "fit": {k: fit.get(k) for k in ("s2", "converged", "stages", "rmse_mV")},
        "coverage": coverage_of(fit, truth),
        "validation_rmse_mV": rmse,
        "seconds": times,
    }


def report(results: list[dict[str, Any]]) -> None:
    for r in results:
        print(f"\nseed {r['seed']}  (wall: " + ", ".join(f"{k} {v:.0f} s" for k, v in r["seconds"].items()) + ")")
        eq = r["equilibrium"] or {}
        for k, v in eq.items():
            print(
                f"  equilibrium {k:12s} {v['estimate']:.6g} truth {v['truth']:.6g} bias {100 * v['bias']:+.3f} % "
                f"covered {v['covered']}"
            )
        x = r["experiments"]
        print(f"  experiments: completed {x['completed']}, replaced {x['replaced']}, lost {x['lost']}")
        f = r["fit"]
        print(
            f"  OED fit: s² {f['s2']:.3g} (target ≤ {S2_TARGET:g}), converged {f['converged']}, "
            f"stages {[(s.get('iterations'), s.get('converged')) for s in f['stages']]}"
        )
        for label, per in r["validation_rmse_mV"].items():
            print(f"  validation {label:12s} " + ", ".join(f"{k} {v:.2f} mV" for k, v in per.items()))
    names = sorted({k for r in results for k in r["coverage"]})
    print("\ncoverage of the truth by the 95 % intervals over the seeds:")
    total, hit = 0, 0
    for n in names:
        vals = [r["coverage"].get(n) for r in results if r["coverage"].get(n) is not None]
        total += len(vals)
        hit += sum(vals)
        print(f"  {n:14s} {sum(vals)}/{len(vals)}")
    if total:
        print(f"  all: {hit}/{total} = {hit / total:.0%} (target ≥ {COVERAGE_TARGET:.0%})")
    s2 = [r["fit"]["s2"] for r in results]
    worst = max((v for r in results for v in r["validation_rmse_mV"].get("OED", {}).values()), default=float("nan"))
    print(
        f"s² of the OED fit: {', '.join(f'{v:.3g}' for v in s2)} (target ≤ {S2_TARGET:g}); worst OED validation "
        f"RMSE {worst:.2f} mV (target ≤ {RMSE_TARGET_MV:g} mV)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base", type=Path, help="a finished full campaign directory (battlab campaign -o BASE)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--fit", choices=("campaign", "lead-in"), default="campaign")
    ap.add_argument("--conventional", action="store_true", help="also the conventional baseline per seed")
    ap.add_argument("--work", type=Path, default=None, help="where the seeds' runs go (default BASE/scale)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.1f} (1 min), {os.cpu_count()} cores")
    shared = shared_inputs(a.base)
    work = a.work or a.base / "scale"
    results = []
    for s in range(a.first_seed, a.first_seed + a.seeds):
        t0 = time.perf_counter()
        results.append(run_seed(a.base, s, work / a.fit, shared, a.fit, a.conventional))
        print(f"seed {s}: {time.perf_counter() - t0:.0f} s", flush=True)
        if a.json:
            a.json.write_text(json.dumps(results, indent=1, default=str))
    report(results)


if __name__ == "__main__":
    main()
