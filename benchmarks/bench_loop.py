"""The closed loop on the in-process virtual tester: design -> run -> fit, with the numbers that say how it went.

1. Sweep a reduced library (the campaign's quick ids, or ``--ids``) on the start cell nca18650 and design
   (``--M`` profiles per group, the paper's Table 9 groups or the ranking's, D-optimal, ``singular="project"``);
   the design's null directions per group are printed (what the projection removed), and each group whose
   information holds an electrode's whole symmetry orbit is designed again in the identifiable coordinates
   (its R_s left out, as the fit holds it): the selections are compared.
2. Run the plan on the in-process virtual tester whose cell is the hidden truth nca18650-true (its preflight and
   window checks are on that cell too), at ``--speed``, noise seed ``--seed``.
3. Print: the samples late / the gaps (missed samples) from the log's run statistics and ``/gaps``; the true
   cell's RMSE on its own log and its weighted residual variance s² (target 0.8-1.25: the noise model
   matches the virtual tester's noise), with the paper's eq. 38 coefficients and with the noise model of step 0;
   the fit's time (target <= 120 s for the full design plan), its estimates and invariants against the truth with
   their 95 % intervals and coverage.

0. (``--noise-trials N``, default 3; 0: none) Before the loop the tester's noise is measured once, as a lab
   calibrates its tester: a plan of N repeated trials of ``--noise-profiles`` charge-only and as many
   discharge-only pulse profiles (those ``battlab design --noise-trials`` picks) runs on the virtual truth (seed
   1000); eq. 38 is fitted to the trials (``battlab fit``'s :mod:`battlab.identify.weights`), compared with the
   tester's own noise level per profile, and saved as ``noise.toml``, which weighs every fit (``--noise``).

``--seeds N`` repeats run and fit with seeds 0..N-1 (``--first-seed K``: K..K+N-1) (one design) and prints the
coverage over seeds: per parameter and invariant the seeds whose 95 % interval holds the truth (eq. 44 as fitted,
and scaled by s²), and per run "covered k of 12": the 12 parameters whose truth lies inside its bounds (the six of
Table 11 on a bound are left out, DESIGN.md § Virtual lab), six point-identified and R_s, D_s, R_f of each electrode
with their set-identified (orbit) intervals; the invariants tau and rho of each electrode beside them (kappa = k/R_s
is left out: its k's truth sits on a bound).

``--sequential``: after the one-shot loop, the sequential design on the same truth and seed: for k = 1..4 the
library is swept at the current estimate, group k (Table 9, cumulative information of groups 1..k) is designed
there and run alone (its own plan, from a full charge), and all logs so far are fitted (stages 1..k, from the
previous estimate). The final estimates of both are printed against the truth, with the mean |log10 error| over
the point-identified parameters and the invariants, and both, with the start cell, are scored on the held-out
validation profiles (:func:`battlab.identify.validation.validation_profiles`, bench_fit's: 0.5C and 1C
discharges, a library sine and pulse train no design selected, HWFET, US06, WLTC3b from SOC 0.6): RMSE [mV]
against the noise-free truth per profile.

    PYTHONPATH=$PWD python benchmarks/bench_loop.py --M 1 --max-iter 10
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

TARGET_FIT_S = 120.0
S2_RANGE = (0.8, 1.25)


def library(work: Path) -> Path:
    from protocols import Library

    lib_path = work / "library.h5"
    if not lib_path.exists():
        Library.build().save(lib_path)
    return lib_path


def design(work: Path, ids: list[int], M: int, groups: str | None, rest_before_s: float = 1800.0) -> Path:
    from battlab.design import workflow as dw

    lib_path = library(work)
    store = work / "store.h5"
    t0 = time.perf_counter()
    dw.sweep(lib_path, "nca18650", store, ids=ids, workers=1)
    t_sweep = time.perf_counter() - t0
    plan = work / "plan.toml"
    t0 = time.perf_counter()
    rep = dw.design(store, plan, M=M, groups_spec=groups, singular="project", rest_before_s=rest_before_s)
    print(f"design: sweep of {len(ids)} profiles {t_sweep:.0f} s, design {time.perf_counter() - t0:.1f} s")
    for d in rep.designs:
        nulls = "; ".join(n.describe() for n in d.unidentifiable) or "none"
        print(f"  group {d.index} {d.new_parameters}: selected {d.selected}; null directions projected out: {nulls}")
    compare_reduced(store, rep.designs, M)
    return plan


def distinct_plan(plan: Path, rest_before_s: float = 1800.0) -> Path:
    """The design's plan with each distinct profile run once, in the first group that selected it (the fit is
    cumulative: later groups fit on it too), beside it as ``plan.distinct.toml`` with the design's summary."""
    import json
    import shutil

    import tomli_w

    from battlab import Cell
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.io.plan import Plan, sidecar_path
    from protocols.protocol import ProfileStep

    steps = [st for st in Plan.load(plan).protocol.steps if isinstance(st, ProfileStep)]
    groups: dict[int, list[Any]] = {}
    seen: set[str] = set()
    for st in steps:
        k = int(st.label.split("group ", 1)[1].split(":")[0])
        if str(st.profile.id) not in seen:
            seen.add(str(st.profile.id))
            groups.setdefault(k, []).append(st.profile)
    out = plan.with_name("plan.distinct.toml")
    table = ocv_table(Cell.load("nca18650"))
    proto = grouped_protocol("distinct", sorted(groups.items()), "distinct", table, rest_before_s=rest_before_s)
    out.write_text(tomli_w.dumps(proto.to_dict()))
    shutil.copy(sidecar_path(plan), sidecar_path(out))
    n = sum(len(v) for v in groups.values())
    ids = json.dumps({k: [p.id for p in v] for k, v in groups.items()})
    print(f"  distinct plan: {n} profile steps of {len(steps)} ({ids})")
    return out


def compare_reduced(store: Path, designs: Any, M: int) -> None:
    """Each group whose parameters hold an electrode's whole orbit, designed on the same candidates (no window
    screen) with ``singular="project"`` and in the identifiable coordinates (R_s left out)."""
    from battlab.design import groups as gd
    from battlab.design import information
    from battlab.design.sweep import SensitivityStore
    from battlab.identify import reduced

    with SensitivityStore.open(store) as s:
        info = information.load(s)
    settings = gd.Settings(M=M, on_singular="project", n_random=0)
    for d in designs:
        fitted, held = reduced.split(d.parameters)
        if not held:
            continue
        a = gd.design_stage(info.F, info, d.parameters, settings, index=d.index)
        b = gd.design_stage(info.F, info, fitted, settings, index=d.index)
        same = sorted(map(str, a.selected)) == sorted(map(str, b.selected))
        print(
            f"  group {d.index} in identifiable coordinates ({', '.join(held)} held): selected {b.selected}, "
            f"{len(b.unidentifiable)} null directions left; projected: {a.selected} "
            f"({len(a.unidentifiable)} projected out); same selection: {same}"
        )


def run(work: Path, plan: Path, seed: int, speed: float) -> Path:
    from battlab.lab.session import RunSettings, start_run

    log = work / f"run-seed{seed}.h5"
    if log.exists():
        log.unlink()
    settings = RunSettings("virtual", "virtual", cell="nca18650-true", speed=speed, seed=seed)
    t0 = time.perf_counter()
    res = start_run(plan, settings, log, display=False)
    print(f"run (seed {seed}): {res.status} {res.reason or ''} in {time.perf_counter() - t0:.0f} s wall")
    return log


def log_quality(log: Path) -> None:
    from battlab.io.logs import read_log

    data = read_log(log)
    stats = (data.meta.get("final") or {}).get("stats", {})
    gaps = data.meta.get("gaps", [])
    missed = sum(max(0.0, b - a - 1.0) for _, a, b in gaps)
    print(
        f"  log: {len(data)} samples over {data.t[-1] - data.t[0]:.0f} s; late samples {stats.get('late_samples')}"
        f" (max {stats.get('max_late_s', float('nan')):.3g} s); gaps {len(gaps)} (about {missed:.0f} samples missed,"
        f" longest {stats.get('max_gap_s', 0.0):.3g} s)"
    )


def noise_calibration(work: Path, trials: int, per_direction: int, speed: float) -> Path:
    """Step 0: the noise trials on the virtual truth, eq. 38 fitted to them, saved as ``noise.toml``."""
    import tomli_w

    from battlab import Cell
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.design.workflow import noise_trial_profiles
    from battlab.identify import runlog
    from battlab.identify.weights import weigh
    from battlab.io.data import load_data
    from battlab.noise import save

    start = Cell.load("nca18650")

    class _Store:  # what noise_trial_profiles reads of a sensitivity store
        attrs = {"library_path": str(library(work))}
        path = work / "store.h5"

    picks = noise_trial_profiles(_Store(), start, per_direction)
    proto = grouped_protocol("noise trials", [], "noise trials", ocv_table(start), picks, trials)
    plan = work / "noise_plan.toml"
    plan.write_text(tomli_w.dumps(proto.to_dict()))
    log = run(work, plan, 1000, speed)
    exps = runlog.experiments(load_data(log), start)
    _, model, info = weigh(exps)
    for t in info["trials"]:
        prof = next(e.profile for e in exps if e.profile.params.get("library_id") == t["profile"])
        actual = tester_noise(prof.current)
        print(
            f"  noise trials of profile {t['profile']} ({t['direction']}, intensity {t['intensity']:.0f}): "
            f"{t['trials']} trials, q {1e6 * t['q_V']:.0f} uV; the tester's noise {1e6 * actual:.0f} uV "
            f"(ratio {t['q_V'] / actual:.2f})"
        )
    path = save(model, work / "noise.toml", source=f"{info['source']} in {log.name}", trials=info["trials"])
    m = model.to_dict()
    print(f"  noise model ({info['source']}): " + ", ".join(f"{k} {v:.4g}" for k, v in m.items()) + f" -> {path}")
    return path


def tester_noise(current: np.ndarray) -> float:
    """The virtual tester's voltage noise [V] under ``current`` [A]: white, current-dependent and quantisation
    (its jitter × dV/dt part left out)."""
    from drivers.virtual.noise import NoiseModel

    m = NoiseModel()
    sigma = m.voltage_white_V + m.voltage_per_amp_V * np.abs(current)
    return float(np.sqrt(np.mean(sigma**2) + m.voltage_quantum_V**2 / 12))


def truth_residuals(log: Path, noise: Path | None, soc_span: float = 0.0) -> None:
    """RMSE and s² of the true cell on its own log (the experiments the fit sees), weighted by the paper's eq. 38
    coefficients and by the noise model ``noise``; each experiment's start SOC is fitted within ``soc_span`` of the
    log's, as the fit frees it (the rest voltage after the preparation's full charge is still relaxing)."""
    from scipy.optimize import minimize_scalar

    from battlab import Cell, parameters
    from battlab.identify import runlog
    from battlab.identify.experiments import variance_of
    from battlab.identify.forward import ForwardModel
    from battlab.io.data import load_data
    from battlab.noise import NoiseModel, load

    truth = Cell.load("nca18650-true")
    exps = runlog.experiments(load_data(log), truth)
    exps = [e for e in exps if not e.profile.params.get("noise_trial")]
    fm = ForwardModel(truth, v_margin=0.15)
    th = np.array([truth.normalised(n) for n in parameters.NAMES])
    models = {"paper's eq. 38": NoiseModel()}
    if noise is not None:
        models[noise.name] = load(noise)
    chi2, n, parts = dict.fromkeys(models, 0.0), 0, []

    def residual(e: Any, soc0: float) -> np.ndarray:
        out = fm.run(th, e.profile, soc0, ambient=e.ambient, T0=e.T0, sample_delay=e.sample_delay)
        k = out.voltage.size
        return (out.voltage - e.voltage[:k])[e.mask[:k]]  # the profile's samples (a lead-in only carries the state)

    for e in exps:
        soc0 = e.soc0
        if soc_span > 0:
            lo, hi = max(e.soc0 - soc_span, 0.0), min(e.soc0 + soc_span, 1.0)
            best = minimize_scalar(
                lambda s, e=e: float(np.sum(residual(e, s) ** 2)),
                bounds=(lo, hi),
                method="bounded",
                options={"xatol": 1e-6},
            )
            soc0 = float(best.x)
        r = residual(e, soc0)
        for name, m in models.items():
            chi2[name] += float(r @ r) / variance_of(e.scored_profile, m)
        n += r.size
        q = 1e3 * np.sqrt(variance_of(e.scored_profile, models[list(models)[-1]]))
        tester = 1e3 * tester_noise(e.scored_profile.current)
        lead = f", lead-in {e.profile.t[e.lead_in]:.0f} s" if e.lead_in else ""
        shift = f", start SOC {soc0 - e.soc0:+.5f}" if soc_span > 0 else ""
        parts.append(
            f"{e.name} {1e3 * np.sqrt(np.mean(r**2)):.2f} mV (q {q:.3f} mV, tester {tester:.3f} mV{lead}{shift})"
        )
    print(f"  truth on its log: RMSE {', '.join(parts)}")
    for name, c in chi2.items():
        s2 = c / n
        ok = "met" if S2_RANGE[0] <= s2 <= S2_RANGE[1] else "MISSED"
        print(f"    s2 with {name}: {s2:.3g} (target {S2_RANGE[0]}-{S2_RANGE[1]}: {ok})")


def invariant_truth(name: str, truth: Any) -> float:
    from battlab.identify.symmetry import INVARIANTS

    e = name.rsplit("_", 1)[1]
    return math.prod(float(truth[p]) ** a for p, a in INVARIANTS[e][name].items())


def interior(name: str, truth: Any) -> bool:
    """Whether the truth of a parameter lies inside its bounds, or (an invariant) none of its parameters' truths
    sits on a bound: coverage is counted there only (DESIGN.md § Virtual lab)."""
    from battlab import parameters
    from battlab.identify.symmetry import INVARIANTS

    if name in parameters.NAMES:
        spec = parameters.SPECS[name]
        v = float(truth[name])
        return spec.lower * (1 + 1e-9) < v < spec.upper * (1 - 1e-9)
    e = name.rsplit("_", 1)[1]
    return all(interior(p, truth) for p in INVARIANTS[e][name])


def fit(
    work: Path,
    logs: list[Path],
    plan: Path | None,
    max_iter: int,
    start: str = "nca18650",
    noise: Path | None = None,
    soc_span: float = 0.0,
) -> tuple[dict[str, tuple[bool, bool | None, bool]], float, float]:
    """Fit the logs from ``start`` in the plan's groups (None: the groups the logs carry), weighted by ``noise``;
    print estimates vs truth; returns ({name: (covered by the 95 % interval, by the s²-scaled one, trusted)} over the
    interior parameters and invariants (:func:`interior`), mean |log10 error| of the point-identified parameters
    and the invariants, the fit's seconds)."""
    from battlab import Cell, parameters, workflow

    truth = Cell.load("nca18650-true")
    t0 = time.perf_counter()

    def stage(k: int, r: Any) -> None:
        c = r.convergence
        print(
            f"  stage {k}: {len(r.names)} fitted, {c.iterations} evaluations, {c.seconds:.0f} s, "
            f"s2 {r.statistics.s2:.3g}, {'converged' if c.converged else c.reason}"
        )

    rep = workflow.fit(
        workflow.FitOptions(
            logs,
            start,
            plan=plan,
            params=None,
            max_iter=max_iter,
            output=work / "fit.bpx.json",
            noise=noise,
            soc_span=soc_span,
        ),
        [workflow.on_stage(stage)],
    )
    secs = time.perf_counter() - t0
    ok = "met" if secs <= TARGET_FIT_S else "MISSED"
    print(f"  fit: {secs:.0f} s (target <= {TARGET_FIT_S:.0f} s for the full design plan: {ok})")
    print(f"  noise model: {rep.summary['noise']['source']}")
    st = rep.last.statistics
    rho, pairs = rep.last.autocorrelation
    caveats = rep.summary.get("trust", {}).get("caveats", [])
    print(f"  residual lag-1 autocorrelation {rho:.3f} (white noise: 0 ± {1 / math.sqrt(max(pairs, 1)):.3f})")
    print(f"  the fit's caveats: {'; '.join(caveats) if caveats else 'none'}")
    root = math.sqrt(st.s2)
    trusted = {**rep.summary["parameters"], **rep.summary.get("invariants", {})}
    covered: dict[str, tuple[bool, bool | None, bool]] = {}
    errors: list[float] = []
    for e in st.estimates:
        tv = float(truth[e.name])
        cov = e.covers(tv)
        sc = e.ci95_scaled
        cov_s = None if sc is None else bool(sc[0] <= tv <= sc[1])
        kind = "set" if e.set_identified else "bound" if e.at_bound else ""
        inside = interior(e.name, truth)
        ci = f"[{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]" if e.ci95 else "-"
        flag = "" if inside else " (truth on a bound: not counted)"
        print(f"    {e.name:12s} {e.value:11.4g} truth {tv:11.4g} ci95 {ci:28s} {kind:5s} covered {cov}{flag}")
        if cov is not None and inside:
            covered[e.name] = (cov, cov_s if not e.set_identified else cov, bool(trusted[e.name].get("trusted")))
        if cov is not None and not e.set_identified:
            errors.append(abs(math.log10(e.value / tv)))
    for i in st.invariants:
        tv = invariant_truth(i.name, truth)
        lo, hi = i.ci95
        cov = lo <= tv <= hi
        lv = math.log(i.value)
        cov_s = math.exp(lv - root * (lv - math.log(lo))) <= tv <= math.exp(lv + root * (math.log(hi) - lv))
        inside = interior(i.name, truth)
        flag = "" if inside else " (a parameter's truth on a bound: not counted)"
        ci = f"[{lo:.4g}, {hi:.4g}]"
        print(f"    {i.name:12s} {i.value:11.4g} truth {tv:11.4g} ci95 {ci:28s} inv   covered {cov}{flag}")
        if inside:
            covered[i.name] = (cov, cov_s, bool(trusted.get(i.name, {}).get("trusted")))
        errors.append(abs(math.log10(i.value / tv)))
    physical = {k: v for k, v in covered.items() if k in parameters.NAMES}
    invs = {k: v for k, v in covered.items() if k not in parameters.NAMES}
    err = float(np.mean(errors)) if errors else float("nan")
    print(
        f"  covered {sum(v[0] for v in physical.values())} of {len(physical)} interior parameters "
        f"({sum(bool(v[1]) for v in physical.values())} with s2-scaled intervals), "
        f"{sum(v[0] for v in invs.values())} of {len(invs)} invariants; s2 {st.s2:.3g}; mean |log10 error| {err:.3f}; "
        f"trusted intervals: {sum(v[0] for v in covered.values() if v[2])} of {sum(v[2] for v in covered.values())} "
        f"cover the truth (trusted: {', '.join(k + ('' if v[0] else ' MISSED') for k, v in covered.items() if v[2])})"
    )
    return covered, err, secs


def plan_ids(plan: Path) -> set[str]:
    """The library ids of a plan's profiles (text)."""
    from battlab.io.plan import Plan
    from protocols.protocol import ProfileStep

    steps = [st for st in Plan.load(plan).protocol.steps if isinstance(st, ProfileStep)]
    return {str(st.profile.params.get("library_id", st.profile.id)) for st in steps}


def validate(cells: dict[str, Path | str], used: set[str]) -> None:
    """RMSE [mV] of each cell (a name or a BPX file) on the held-out validation profiles, none of ``used``,
    against the noise-free truth, beside the noise level of each profile (bench_fit's table). Each cell runs on a
    forward model of its own (a fit may change non-dynamic values, e.g. eps_s_p)."""
    from battlab import Cell
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import format_table, rmse_table, validation_profiles
    from battlab.identify.virtual import synthesize
    from protocols import Library

    truth = Cell.load("nca18650-true")
    fm = ForwardModel(Cell.load("nca18650"))
    val = validation_profiles(fm, truth, Library.build(), used)
    vexps = [synthesize(fm, truth, p, s, seed=99, name=str(p.id)) for p, s in val]
    table: dict[str, dict[str, float]] = {}
    for label, path in cells.items():
        cell = Cell.load(str(path))
        table.update(rmse_table(ForwardModel(cell), {label: cell}, vexps)[0])
    noise = {e.name: 1e3 * float(np.sqrt(e.variance[0])) for e in vexps}
    print("validation RMSE against the noise-free truth\n" + format_table({**table, "noise σ": noise}))
    labels = list(table)
    print("  mean RMSE [mV]: " + ", ".join(f"{k} {np.mean(list(table[k].values())):.2f}" for k in labels))


def sequential(
    work: Path, ids: list[int], M: int, max_iter: int, seed: int, speed: float, noise: Path | None = None
) -> tuple[float, Path, set[str]]:
    """The sequential design (see the module docstring); returns the final mean |log10 error|, the final
    estimate's BPX file and the library ids the designs selected."""
    import json

    from battlab import Cell
    from battlab.design import workflow as dw
    from battlab.parameters import TABLE9_GROUPS

    lib_path = library(work)
    start, logs, err, used = "nca18650", [], float("nan"), set()
    for k in range(1, len(TABLE9_GROUPS) + 1):
        wk = work / f"seq{k}"
        wk.mkdir(parents=True, exist_ok=True)
        (wk / "groups.json").write_text(json.dumps([list(g) for g in TABLE9_GROUPS[:k]]))
        t0 = time.perf_counter()
        dw.sweep(lib_path, Cell.load(start), wk / "store.h5", ids=ids, workers=1)
        rep = dw.design(wk / "store.h5", wk / "plan.toml", M=M, groups_spec=str(wk / "groups.json"))
        d = rep.designs[k - 1]
        print(f"sequential group {k}: designed at {start} in {time.perf_counter() - t0:.0f} s: selected {d.selected}")
        used |= plan_ids(rep.files.groups[k - 1])
        logs.append(run(wk, rep.files.groups[k - 1], seed, speed))
        log_quality(logs[-1])
        _, err, _ = fit(wk, logs, None, max_iter, start, noise)
        start = str(wk / "fit.bpx.json")
    return err, Path(start), used


def main() -> None:
    from battlab.campaign.config import QUICK_LIBRARY_IDS
    from protocols.errors import InputError

    logging.getLogger("pymodbus").setLevel(logging.WARNING)

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ids", default=",".join(map(str, QUICK_LIBRARY_IDS)), help="library ids to sweep")
    ap.add_argument("--M", type=int, default=2, help="profiles per group")
    ap.add_argument("--groups", default="paper", help="'paper' (Table 9) or a groups JSON; '' for the ranking's")
    ap.add_argument("--max-iter", type=int, default=40, help="evaluations per fit stage (battlab fit's default)")
    ap.add_argument(
        "--speed", type=float, default=100.0, help="virtual clock speed (1000 on a loaded 2-core host: late samples)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, default=0, help="repeat run and fit for seeds 0..N-1 (coverage)")
    ap.add_argument("--first-seed", type=int, default=0, help="with --seeds: seeds K..K+N-1 (a run split in parts)")
    ap.add_argument("--noise-trials", type=int, default=3, help="repeated trials of the noise calibration (0: none)")
    ap.add_argument(
        "--noise-profiles", type=int, default=3, help="noise profiles per direction (the campaign's default: 3)"
    )
    ap.add_argument(
        "--soc-span",
        type=float,
        default=0.01,
        help="fit each experiment's start SOC within +- this (the campaign's fits do; 0: the log's rest-voltage SOC)",
    )
    ap.add_argument("--noise", default=None, help="a noise model file measured before (instead of the calibration)")
    ap.add_argument(
        "--distinct",
        action="store_true",
        help="run each distinct profile of the design once (a profile selected by "
        "several groups runs in the first; the cumulative fit sees it in the later stages too)",
    )
    ap.add_argument("--rest-before", type=float, default=1800.0, help="rest before every profile [s]")
    ap.add_argument("--sequential", action="store_true", help="also the sequential design (see above)")
    ap.add_argument("--sequential-only", action="store_true", help="the sequential design alone")
    ap.add_argument("--workdir", default=None)
    a = ap.parse_args()
    work = Path(a.workdir or tempfile.mkdtemp(prefix="bench_loop-"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("BATTLAB_HOME", str(work / "home"))
    print(f"work directory {work}")
    seeds = list(range(a.first_seed, a.first_seed + a.seeds)) if a.seeds else [a.seed]
    noise = Path(a.noise) if a.noise else None
    if a.noise_trials and noise is None:
        t0 = time.perf_counter()
        noise = noise_calibration(work, a.noise_trials, a.noise_profiles, a.speed)
        print(f"noise calibration: {time.perf_counter() - t0:.0f} s")
    if a.sequential_only:
        seq, seq_cell, used = sequential(
            work, [int(x) for x in a.ids.split(",")], a.M, a.max_iter, seeds[-1], a.speed, noise
        )
        print(f"mean |log10 error|: sequential {seq:.3f} (seed {seeds[-1]})")
        validate({"nominal": "nca18650", "sequential": seq_cell}, used)
        return
    plan = design(work, [int(x) for x in a.ids.split(",")], a.M, a.groups or None, a.rest_before)
    if a.distinct:
        plan = distinct_plan(plan, a.rest_before)
    tally: dict[str, list[tuple[bool, bool | None]]] = {}
    per_run: list[str] = []
    fit_s: list[float] = []
    one_shot = float("nan")
    for seed in seeds:
        log = run(work, plan, seed, a.speed)
        log_quality(log)
        try:
            truth_residuals(log, noise, a.soc_span)
        except InputError as exc:
            print(f"  no fit: {exc}")
            continue
        covered, one_shot, secs = fit(work, [log], plan, a.max_iter, noise=noise, soc_span=a.soc_span)
        fit_s.append(secs)
        for k, v in covered.items():
            tally.setdefault(k, []).append(v)
        from battlab import parameters

        phys = [v[0] for k, v in covered.items() if k in parameters.NAMES]
        per_run.append(f"seed {seed}: covered {sum(phys)} of {len(phys)}")
    if len(seeds) > 1:
        print(f"coverage over {len(seeds)} seeds (95 % interval as fitted; s2-scaled; the trusted ones):")
        for k, v in tally.items():
            scaled = [x[1] for x in v if x[1] is not None]
            tr = [x[0] for x in v if x[2]]
            cov = f"{sum(x[0] for x in v)}/{len(v)}; {sum(scaled)}/{len(scaled)}"
            print(f"  {k:12s} {cov}; trusted {sum(tr)}/{len(tr)}")
        print("per run (interior parameters): " + "; ".join(per_run))
        trusted = [x[0] for v in tally.values() for x in v if x[2]]
        if trusted:
            scaled = [bool(x[1]) for v in tally.values() for x in v if x[2]]
            print(
                f"trusted intervals over the seeds: {sum(trusted)} of {len(trusted)} cover the truth "
                f"({100 * sum(trusted) / len(trusted):.0f} %; nominal 95 %), {sum(scaled)} scaled by s2 "
                f"({100 * sum(scaled) / len(scaled):.0f} %); "
                f"{sum(x[2] for v in tally.values() for x in v)} of {sum(len(v) for v in tally.values())} trusted"
            )
        if fit_s:
            print(f"fit time: median {np.median(fit_s):.0f} s, max {max(fit_s):.0f} s")
    if a.sequential:
        ids = [int(x) for x in a.ids.split(",")]
        seq, seq_cell, used = sequential(work, ids, a.M, a.max_iter, seeds[-1], a.speed, noise)
        print(f"mean |log10 error|: one-shot {one_shot:.3f}, sequential {seq:.3f} (seed {seeds[-1]})")
        cells: dict[str, Path | str] = {"nominal": "nca18650"}
        if fit_s:  # the one-shot fit of the last seed that ran to a fit
            cells["one-shot"] = work / "fit.bpx.json"
        validate({**cells, "sequential": seq_cell}, used | plan_ids(plan))


if __name__ == "__main__":
    main()
