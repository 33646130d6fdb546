"""Benchmark: full group-wise identification on the virtual truth, the conventional baseline, validation, coverage.

    python benchmarks/bench_fit.py [--seeds 20] [--per-group 3] [--candidates 40] [--quick]

Data from ``nca18650-true`` plus noise at the noise-model level; every fit starts from ``nca18650``. Prints the
time of the full group-wise fit (target ≤ 10 min), the recovery table (truth, estimate, interval, covered?;
parameters whose truth sits on a bound are excluded from coverage, as DESIGN.md says, and so are parameters in
a null direction of the information matrix: R_s, D_s, R_f, k of each electrode are dependent, see
:mod:`battlab.identify.statistics`), the validation RMSE table (nominal, conventional, OED; against the noise-free
truth), the interval coverage over seeds (seeds ≥ 1 refit the final stage from seed 0's estimate unless
``--coverage-full``), and saves ``coverage.png``. Profiles for the OED-like fit: the stand-in greedy D-optimal selection
(:mod:`battlab.identify.selection`) from every ``len(library)/candidates``-th library profile.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import battlab
from battlab import parameters as P
from battlab.identify import conventional
from battlab.identify import fit as F
from battlab.identify.forward import ForwardModel
from battlab.identify.selection import greedy_d_optimal, information
from battlab.identify.validation import cut_at_limit, discharge_profiles, format_table, rmse_table
from battlab.identify.virtual import noise_free, synthesize
from protocols.drive_cycles import Cycle, drive_profile
from protocols.library import Library


def _status(e) -> bool | str:
    """Covered (bool), or why the parameter is excluded from coverage."""
    spec = P.SPECS[e.name]
    if spec.truth in (spec.lower, spec.upper):
        return "excluded: truth on a bound"
    if not e.identifiable:
        return "excluded: not identifiable"
    if e.ci95 is None:
        return "excluded: no interval"
    return e.covers(spec.truth)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--per-group", type=int, default=3)
    ap.add_argument("--candidates", type=int, default=40)
    ap.add_argument("--max-nfev", type=int, default=40)
    ap.add_argument("--coverage-only", action="store_true",
                    help="skip the group-wise and conventional fits: final-stage fits from the truth, all seeds")
    ap.add_argument("--coverage-full", action="store_true",
                    help="coverage seeds rerun the whole group-wise fit (default: only the final stage, from seed "
                         "0's estimate; the intervals are the final stage's either way)")
    ap.add_argument("--quick", action="store_true", help="2 seeds, 2 profiles per group, 20 candidates")
    a = ap.parse_args()
    if a.quick:
        a.seeds, a.per_group, a.candidates = 2, 2, 20
    nominal, truth = battlab.Cell.load("nca18650"), battlab.Cell.load("nca18650-true")
    fm = ForwardModel(nominal)
    lib = Library.build()
    t0 = time.perf_counter()
    cands = list(lib)[:: max(len(lib) // a.candidates, 1)]
    ok = [p for p in cands if fm.run(fm.theta_of(truth), p, p.soc0).ended_by is None]
    groups = F.TABLE9_GROUPS
    chosen: list[list] = []
    used: set = set()
    for g in groups:
        info = information(fm, nominal, [p for p in ok if p.id not in used], g)
        ids = greedy_d_optimal(info, a.per_group)
        used |= set(ids)
        chosen.append([lib[i] for i in ids])
    print(f"selection (stand-in D-optimal) {time.perf_counter() - t0:.1f} s: "
          + "; ".join(f"group {k + 1}: {[p.id for p in c]}" for k, c in enumerate(chosen)))
    clean = {p.id: noise_free(fm, truth, p, p.soc0) for c in chosen for p in c}
    val_profiles = _validation_profiles(fm, truth, lib, used)
    names_all = tuple(n for g in groups for n in g)
    if a.coverage_only:  # the final stage's estimator only, started at the truth
        _coverage(a, fm, nominal, truth, chosen, clean, names_all, truth, [])
        return

    def run(seed: int, verbose: bool) -> tuple[list[F.FitResult], F.FitResult | None]:
        stages = [F.Stage(g, tuple(synthesize(fm, truth, p, p.soc0, seed=seed * 10000 + int(p.id), clean=clean[p.id])
                                   for p in c)) for g, c in zip(groups, chosen, strict=True)]
        t1 = time.perf_counter()
        res = F.fit_groupwise(nominal, stages, forward=fm, options=F.Options(max_nfev=a.max_nfev),
                              progress=(lambda k, r: print(f"  stage {k}: {r.convergence.iterations} evaluations, "
                                                           f"{r.convergence.seconds:.1f} s, {r.convergence.reason}"))
                              if verbose else None)
        if verbose:
            print(f"full group-wise fit: {time.perf_counter() - t1:.1f} s (target <= 600 s)")
        conv = None
        if verbose:
            cexps = conventional.virtual_experiments(fm, truth, seed=seed)
            oed_h = sum(e.hours for s in stages for e in s.experiments)
            print(f"conventional: {conventional.hours(cexps):.1f} test hours vs OED {oed_h:.1f} h")
            conv = F.fit(nominal, cexps, P.NAMES, forward=fm, options=F.Options(max_nfev=a.max_nfev))
            print(f"conventional fit: {conv.convergence.iterations} evaluations, {conv.convergence.seconds:.1f} s")
        return res, conv

    res, conv = run(0, True)
    last = res[-1]
    print("\nrecovery (seed 0): name, truth, estimate, 95 % interval, covered (excluded: truth on a bound, or not "
          "identifiable = in a null direction of JᵀWJ)")
    for e in last.statistics.estimates:
        spec = P.SPECS[e.name]
        cov = _status(e)
        ci = f"[{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]" if e.ci95 else "none"
        print(f"  {e.name:12s} {spec.truth:11.4g} {e.value:11.4g} {ci:26s} {cov} {e.at_bound or ''}")
    if last.statistics.reason:
        print("  statistics:", last.statistics.reason)
    vexps = [synthesize(fm, truth, p, s, seed=99, name=str(p.id)) for p, s in val_profiles]
    cells = {"nominal": nominal, "conventional": conv.cell, "OED": last.cell}
    table, _ = rmse_table(fm, cells, vexps)
    print("\nvalidation RMSE against the noise-free truth\n" + format_table(table))
    beats = all(table["OED"][n] < table["conventional"][n] for n in table["OED"])
    noise = {e.name: 1e3 * np.sqrt(e.variance[0]) for e in vexps}
    print(f"OED beats conventional on every profile: {beats}; OED RMSE <= 2x noise: "
          f"{all(table['OED'][n] <= 2 * noise[n] for n in noise)}")
    last.cell.to_bpx("oed.json")
    conv.cell.to_bpx("conventional.json")
    print("saved oed.json and conventional.json")
    covered = [_status(e) for e in last.statistics.estimates if isinstance(_status(e), bool)]
    if a.coverage_full:
        per_run = [sum(covered)]
        for seed in range(1, a.seeds):
            r, _ = run(seed, False)
            c = [_status(e) for e in r[-1].statistics.estimates if isinstance(_status(e), bool)]
            covered += c
            per_run.append(sum(c))
        _report_coverage(covered, per_run, a.seeds)
    else:
        _coverage(a, fm, nominal, truth, chosen, clean, last.names, last.cell, covered)


def _validation_profiles(fm, truth, lib, used) -> list:
    """Held-out profiles: 0.5C and 1C discharges, a sinusoid and a pulse train from the library that were not
    selected, and the HWFET, US06 and WLTC class 3b drive cycles from SOC 0.6 (from 0.8 HWFET's
    regenerative peaks reach V_max) (cut where the truth stops)."""
    out = [(cut_at_limit(fm, truth, p, s), s) for p, s in discharge_profiles(truth)]
    th = fm.theta_of(truth)
    for kind in ("sine", "pulse"):
        for p in list(lib)[7::13]:
            if p.kind == kind and p.id not in used and fm.run(th, p, p.soc0).ended_by is None:
                out.append((p, p.soc0))
                break
    for cyc in (Cycle.HWFET, Cycle.US06, Cycle.WLTC3B):
        p = drive_profile(cyc, soc0=0.6, id=cyc.name)
        out.append((cut_at_limit(fm, truth, p, 0.6), 0.6))
    return out


def _coverage(a, fm, nominal, truth, chosen, clean, names, start, covered) -> None:
    """Seeds ≥ 1 (all seeds from ``--coverage-only``): refit the final stage (all groups, all data) from
    ``start``; coverage of the identifiable interior parameters."""
    per_run = [sum(covered)] if covered else []
    first = 0 if a.coverage_only else 1
    for seed in range(first, a.seeds):
        t1 = time.perf_counter()
        exps = [synthesize(fm, truth, p, p.soc0, seed=seed * 10000 + int(p.id), clean=clean[p.id])
                for c in chosen for p in c]
        r = F.fit(nominal, exps, names, forward=fm, start=start, options=F.Options(max_nfev=a.max_nfev))
        c = [_status(e) for e in r.statistics.estimates if isinstance(_status(e), bool)]
        missed = [e.name for e in r.statistics.estimates if _status(e) is False]
        covered += c
        per_run.append(sum(c))
        print(f"  seed {seed}: {sum(c)}/{len(c)} covered (missed {missed}), {r.convergence.iterations} evaluations, "
              f"{r.convergence.reason[:40]}, {time.perf_counter() - t1:.0f} s", flush=True)
    _report_coverage(covered, per_run, a.seeds - first + (1 if covered and first else 0))


def _report_coverage(covered: list, per_run: list, seeds: int) -> None:
    if not covered:
        return
    print(f"\ncoverage over {len(per_run)} seeds (identifiable interior parameters): {np.mean(covered):.3f} "
          f"({sum(covered)}/{len(covered)}); covered per run: {per_run}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3))
    ax.bar(["covered", "missed"], [sum(covered), len(covered) - sum(covered)])
    ax.set_title(f"95 % interval coverage {np.mean(covered):.1%} ({len(per_run)} seeds)")
    fig.tight_layout()
    fig.savefig("coverage.png", dpi=100)
    print("saved coverage.png")


if __name__ == "__main__":
    main()
