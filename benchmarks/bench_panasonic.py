"""Benchmark: the Panasonic NCR18650PF real cell (../shared/data/panasonic-18650pf), 25 °C.

    python benchmarks/bench_panasonic.py [--hppc-every 2] [--max-nfev 25] [--quick]

1. Equilibrium from the C/20 test (mean of the discharge and charge branches), with a 6-term correction of the
   positive OCP (the base cell's OCPs are stand-ins for this cell's); RMSE over 5–95 % SOC.
2. Dynamics from HPPC (every ``--hppc-every``-th pulse segment between logging gaps, above 10 % SOC) and US06 up
   to 90 % of its discharged charge, resampled to 1 s,
   with a reduced parameter set (:data:`NAMES`: the model is unchanged by (R_s, D_s, k, R_f) → (λR_s, λ²D_s, λk,
   R_f/λ) in each electrode, :mod:`battlab.identify.symmetry`, so R_s± are held at their nominal values, and
   near-linear kinetics make k and R_f nearly interchangeable, so one of them per electrode is kept) plus one
   start-SOC nuisance parameter per experiment (±5 % around the SOC from the rest voltage / Ah column).
3. Prediction of HWFET (start SOC from its first rest voltage, no nuisance) with the equilibrium-only cell and the
   fitted cell, over the whole test and up to 90 % of its discharged charge. Prints the RMSEs [mV].
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import battlab
from battlab.identify import fit as F
from battlab.identify.equilibrium import fit_equilibrium, ocv_curve
from battlab.identify.experiments import Experiment, experiments_from_data
from battlab.identify.forward import ForwardModel
from battlab.identify.validation import predict
from battlab.io.data import load_data

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "panasonic-18650pf"
#: Reduced parameter set for the real cell (see the module docstring).
NAMES = ("D_s_n", "D_s_p", "R_f_n", "k_p", "kappa_scale", "D_e_scale", "eps_e_s")


def _load(name: str):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_data(DATA / f"25degC_{name}.mat")


def _until_90(e: Experiment, total_ah: float) -> Experiment:
    """``e`` with its mask limited to the samples before 90 % of ``total_ah`` has been discharged (Table 12's
    convention; the end of discharge, where the cell's usable capacity at these currents and its ageing decide
    the voltage, is scored separately)."""
    dq = -np.concatenate([[0.0], np.cumsum(e.profile.current[:-1] * np.diff(e.profile.t))]) / 3600.0
    mask = e.mask & (dq <= 0.9 * total_ah)
    return Experiment(e.name, e.profile, e.voltage, e.soc0, e.variance, e.ambient, e.T0, mask)


def _ah(e: Experiment) -> float:
    return float(-np.sum(e.profile.current[:-1] * np.diff(e.profile.t)) / 3600.0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--hppc-every", type=int, default=3)
    ap.add_argument("--max-nfev", type=int, default=15)
    ap.add_argument("--quick", action="store_true", help="every 4th HPPC segment, 6 evaluations")
    a = ap.parse_args()
    if a.quick:
        a.hppc_every, a.max_nfev = 4, 6
    t0 = time.perf_counter()
    d = _load("C20_OCV")
    curve = ocv_curve(d.t, d.current, d.voltage, source=d.source)
    eq = fit_equilibrium(curve, battlab.Cell.load("nca18650"), ocp_terms=6, rated_capacity=2.9)
    print(
        f"equilibrium (C/20, {curve.method}): capacity {eq.capacity:.3f} Ah, RMSE {eq.rmse_mV:.2f} mV overall, "
        f"{eq.rmse_5_95_mV:.2f} mV over 5-95 % SOC (max {eq.max_error_5_95_mV:.1f} mV), "
        f"{time.perf_counter() - t0:.1f} s"
    )
    cell = eq.cell
    fm = ForwardModel(cell, v_margin=0.15)
    hppc = experiments_from_data(_load("HPPC"), cell, dt=1.0)
    us06 = experiments_from_data(_load("US06"), cell, dt=1.0)
    hwfet = experiments_from_data(_load("HWFET"), cell, dt=1.0)
    # fit on HPPC segments above 10 % SOC and US06 up to 90 % of its discharged charge
    train = [e for e in hppc[:: a.hppc_every] if e.soc0 >= 0.1] + [_until_90(e, _ah(e)) for e in us06]
    print(
        f"fit data: {len(train) - 1} of {len(hppc)} HPPC segments + US06 to 90 % of its charge "
        f"({sum(int(e.mask.sum()) for e in train)} samples at 1 s); parameters {', '.join(NAMES)} "
        f"+ {len(train)} start-SOC nuisances"
    )
    res = F.fit(cell, train, NAMES, forward=fm, options=F.Options(max_nfev=a.max_nfev), soc_span=0.05)
    c = res.convergence
    print(f"fit: {c.iterations} evaluations, {c.seconds:.0f} s, cost {c.cost_start:.4g} -> {c.cost:.4g}, {c.reason}")
    print("  name          start        estimate   95 % (Cov·s², the residuals are model error, not noise)")
    for e in res.statistics.estimates:
        ci = f"[{e.ci95_scaled[0]:.4g}, {e.ci95_scaled[1]:.4g}]" if e.ci95_scaled else "none"
        print(f"  {e.name:12s} {float(cell.get(e.name)):11.4g} -> {e.value:11.4g}  {ci} {e.at_bound or ''}")
    st = res.statistics
    print(
        f"  s2 = {st.s2:.3g} (weighted residual variance; >> 1 means model error dominates the noise)"
        + (f"; {st.reason}" if st.reason else "")
    )
    socs = res.extra.get("soc0", {})
    print(
        "  start SOC (data -> fitted): "
        + ", ".join(f"{e.name} {e.soc0:.3f}->{socs.get(e.name, e.soc0):.3f}" for e in train)
    )
    print("\nRMSE [mV]            equilibrium only    fitted")
    for e in train:
        print(f"  {e.name:18s} {res.rmse_before_mV[e.name]:14.2f} {res.rmse_mV[e.name]:12.2f}   (fit data)")
    for e in hwfet:
        before = predict(fm, cell, e)
        after = predict(fm, res.cell, e)
        m = _until_90(e, _ah(e)).mask
        for label, sel in (("whole test", slice(None)), ("to 90 % of its charge", m)):
            rm = [float(1e3 * np.sqrt(np.nanmean((p[sel] - e.voltage[sel]) ** 2))) for p in (before, after)]
            print(f"  {e.name:18s} {rm[0]:14.2f} {rm[1]:12.2f}   (HWFET prediction, {label})")
        o = fm.run(fm.theta_of(res.cell), e.profile, e.soc0, ambient=e.ambient, T0=e.T0, sample_delay=e.sample_delay)
        k = o.voltage.size
        print(
            f"  {e.name:18s} {'':14s} {1e3 * np.sqrt(np.mean((o.voltage - e.voltage[:k]) ** 2)):12.2f}   (HWFET "
            f"prediction until the fitted model stops: {o.ended_by or 'end'} at {e.profile.t[k - 1]:.0f} s of "
            f"{e.profile.t[-1]:.0f} s)"
        )
        err = 1e3 * (after - e.voltage)
        q = len(err) // 10
        print(
            "  HWFET error by tenth of the test [mV RMSE]: "
            + ", ".join(f"{np.sqrt(np.mean(err[k * q : (k + 1) * q] ** 2)):.1f}" for k in range(10))
        )
        print(f"  HWFET start SOC {e.soc0:.3f}; it delivers {_ah(e):.3f} Ah to 2.5 V vs {eq.capacity:.3f} Ah at C/20")
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
