"""``battlab diagnose`` as an instrument: its error rates measured on seeded hidden-effect cases (the confusion table).

Run: ``python benchmarks/bench_diagnose.py --cases 24 --nulls 10 --seed 1 --profile rich`` (30-60 min of CPU on
2 cores), ``--timing`` for one diagnosis of 4 h of data at 1 s, ``--json out.json`` to save every case.

Each case: the nominal cell (nca18650) with one catalog extension switched on at a size drawn at random from
``SIZES`` (realistic ranges, the source or reason beside each), simulated on the profile, plus the virtual tester's
physical measurement noise (:class:`drivers.virtual.noise.NoiseModel`: white ADC noise, a component growing with
|I|, sampling jitter × dV/dt clipped to the last step's change, 100 µV quantisation; the logged current has its own
white noise and 10 µA quantisation), written as a BDF CSV and diagnosed with the base cell
(:func:`battlab.diagnose.workflow.diagnose`). Null cases are the nominal cell and the noise only. Causes are
drawn in turn (case k has cause ``CAUSES[k % 8]``), so 24 cases give 3 per cause.

Profiles (1 s samples, 25 °C ambient, from SOC 0.8):

- ``drive``: 1 h of the UDDS drive cycle (the library's EV-model current);
- ``rich``: about 1.1 h: a rest, discharge pulses (1C, 2C, 30-60 s), a rest after discharge, 10 min of UDDS, a
  1C charge and a rest after it, a C/2 discharge, a rest, 5 min of UDDS. Directions change and rests follow
  both charge and discharge, so hysteresis and OCV effects have a chance; the final 30 % is held out.

Thermal cases: activation energies act only through a change of temperature, and the diagnosis reads one ambient
per file, so a thermal case is the same profile at ``THERMAL_AMBIENTS_C`` (25 and 10 °C training, 40 °C held out:
the truth, the engine's ambient and the logged ambient per file). ``--one-ambient-thermal`` adds thermal cases at
25 °C only (row ``thermal@1T``), right as "cannot tell" (``untestable``: one ambient) naming the experiment.

Outcome per case: the named cause, ``cannot tell`` (no cause named, and the summary's ``cannot_tell``,
``untestable`` or ``undetectable`` lists the true cause with the experiment that would tell; for a null case any
``cannot_tell`` entry), else ``null``. The confusion table counts true cause × outcome; "right" (strict) is the
named cause equal to the true one.

Visibility, measured outside the diagnosis's decision: the oracle. The true extension is fitted on the training
part beside the same base parameters, from the same start with the same optimiser and stopping rule as the
diagnosis's base fit (``DiagnoseOptions.also_fit``), whatever the score tests say; the effect is
"visible on this data" when that oracle passes the naming rule, a held-out RMSE gain of at least 30 % over the
base fit. Chosen over the noise-free effect left after refitting the base (against the measured noise) because it
asks the very question the naming rule asks (does knowing the true model predict unseen data better?), it counts
the effect's held-out consequences instead of its in-sample size (a capacity fade of mV over the training part
that the base absorbs is not visible), and it needs no noise-free twin of measured data. Its limits: a fit stuck
in a local minimum makes an effect look invisible, and an effect visible to the oracle may still be beyond the
score test's power. The visibility table scores a visible case right when the true cause is named, an invisible
one when no wrong cause is named (cannot tell naming it, null, or the true cause); both rates are printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import battlab  # noqa: E402
from drivers.virtual.noise import NoiseModel  # noqa: E402
from protocols import Profile  # noqa: E402
from protocols.drive_cycles import Cycle, drive_profile  # noqa: E402

CELL = "nca18650"
SOC0 = 0.8
AMBIENT_C = 25.0
#: a thermal case's files: the same profile at these ambients [degC], the last held out
THERMAL_AMBIENTS_C = (25.0, 10.0, 40.0)
CAUSES = (
    "contact_resistance",
    "current_sensor",
    "thermal",
    "equilibrium",
    "hysteresis",
    "double_layer",
    "capacity_fade",
    "electrolyte",
)


def _sign(rng: np.random.Generator) -> float:
    return float(rng.choice([-1.0, 1.0]))


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


#: per cause: a function drawing its parameter values, and the source / reason of the ranges
SIZES: dict[str, tuple[Callable[[np.random.Generator], dict[str, float]], str]] = {
    "contact_resistance": (
        lambda g: {"R_c": _u(g, 0.002, 0.010)},
        "2-10 mOhm: an 18650 in a spring or clamp holder with 4-wire sense above the tabs (Guo et al. 2011; "
        "holder datasheets quote 1-10 mOhm)",
    ),
    "current_sensor": (
        lambda g: {"offset": _sign(g) * _u(g, 0.005, 0.030), "gain": _sign(g) * _u(g, 0.001, 0.01)},
        "offset 5-30 mA, gain 0.1-1 %: cycler current accuracy 0.02-0.1 % of a 5-30 A range plus drift after "
        "calibration (Arbin LBT, Maccor 4000 specifications)",
    ),
    "thermal": (
        lambda g: {
            "dE_D_s_n": _sign(g) * _u(g, 5e3, 15e3),
            "dE_k_p": _sign(g) * _u(g, 5e3, 15e3),
            "h2a_scale": float(np.exp(g.uniform(np.log(0.5), np.log(2.0)))),
            "dUdT_offset": _sign(g) * _u(g, 2e-5, 1e-4),
        },
        "activation energies +-5-15 kJ/mol (published values for one material spread by 30-50 % of 20-50 kJ/mol); "
        "surface heat transfer x0.5-2 (fixture and airflow); entropic coefficient +-0.02-0.1 mV/K",
    ),
    "equilibrium": (
        lambda g: {
            "d_sto_n": _sign(g) * _u(g, 0.003, 0.015),
            "d_sto_p": _sign(g) * _u(g, 0.003, 0.015),
            "dU": _sign(g) * _u(g, 0.001, 0.005),
        },
        "stoichiometry shifts 0.3-1.5 % and an OCV offset 1-5 mV: electrode balancing from a C/20 test and "
        "cell-to-cell spread (Mohtat et al. 2019)",
    ),
    "hysteresis": (
        lambda g: {
            "M_n": _u(g, 0.005, 0.020),
            "gamma_n": _u(g, 20.0, 100.0),
            "M_p": _u(g, 0.0, 0.010),
            "gamma_p": _u(g, 20.0, 100.0),
        },
        "graphite half-width 5-20 mV, NCA 0-10 mV, decay 20-100 per unit stoichiometry (Axen et al. 2022; "
        "GITT charge/discharge OCV gaps of 10-40 mV)",
    ),
    "double_layer": (
        lambda g: {"C_dl_n": _u(g, 0.1, 0.5), "C_dl_p": _u(g, 0.1, 0.5)},
        "0.1-0.5 F/m2 (10-50 uF/cm2 of particle surface, EIS of graphite and NCA)",
    ),
    "capacity_fade": (
        lambda g: {"I_side": _u(g, 0.5e-3, 3e-3), "lam_n": _u(g, 0.0, 2e-3), "lam_p": _u(g, 0.0, 2e-3)},
        "side current 0.5-3 mA and active-material loss up to 0.2 %/h: the fast end (first cycles after "
        "formation, 45 degC cycling); a calendar-aged cell loses ~1 %/month, invisible in 1-2 h",
    ),
    "electrolyte": (
        lambda g: {
            "De_slope": _sign(g) * _u(g, 0.2, 0.6),
            "kappa_slope": _sign(g) * _u(g, 0.2, 0.6),
            "dlnf_slope": _sign(g) * _u(g, 0.2, 0.6),
        },
        "relative slopes 0.2-0.6 per 1000 mol/m3: the spread of LiPF6 carbonate property fits over 0.5-1.5 M "
        "(Valoen and Reimers 2005)",
    ),
    "solid_diffusion": (
        lambda g: {"b_n": _sign(g) * _u(g, 1.0, 3.0), "b_p": _sign(g) * _u(g, 1.0, 3.0)},
        "log-slopes 1-3 per unit stoichiometry: D_s over an electrode's window changes 3-20 fold (GITT of graphite "
        "and NCA, Ecker et al. 2015)",
    ),
}


def profile(kind: str, q: float, hours: float | None = None) -> Profile:
    """The test profile [A, + = charge] on a 1 s grid; ``hours``: repeat it to this length (the timing case)."""
    udds = drive_profile(Cycle.UDDS)
    if kind == "drive":
        t = np.arange(0.0, 3601.0)
        i = udds.value_at(np.mod(t, float(udds.t[-1])))
    elif kind == "rich":
        pieces = [
            (300, 0.0),
            *[(d, -c * q) for d, c in ((60, 1.0), (60, 0.0), (30, 2.0), (60, 0.0), (60, 1.0), (60, 0.0))],
            (30, -2.0 * q),
            (600, 0.0),  # rest after discharge
            ("udds", 600),
            (480, 1.0 * q),  # 1C charge
            (600, 0.0),  # rest after charge
            (480, -0.5 * q),
            (300, 0.0),
            ("udds", 300),
        ]
        ts, cs, t0 = [], [], 0.0
        for a, b in pieces:
            if a == "udds":
                tt = np.arange(0.0, float(b))
                ts.append(t0 + tt)
                cs.append(udds.value_at(tt))
                t0 += float(b)
            else:
                ts.append(t0 + np.arange(0.0, float(a)))
                cs.append(np.full(int(a), float(b)))
                t0 += float(a)
        t = np.concatenate([*ts, [t0]])
        i = np.concatenate([*cs, [0.0]])
    else:
        raise SystemExit(f"--profile: expected drive or rich, got {kind!r}")
    if hours is not None:
        n = int(np.ceil(hours * 3600.0 / t[-1]))
        # repeated as is (the rich profile nets -0.15 SOC per repeat: 4 h end near SOC 0.25; its mirror, charging
        # with 2C pulses from SOC 0.8, passes 4.2 V)
        blocks = [i[:-1]] * n
        i = np.concatenate([*blocks, [0.0]])[: int(hours * 3600) + 1]
        t = np.arange(0.0, float(i.size))
    return Profile(t, i, id=kind)


def noisy(
    v: np.ndarray, i: np.ndarray, t: np.ndarray, rng: np.random.Generator, nm: NoiseModel
) -> tuple[np.ndarray, np.ndarray]:
    """The virtual tester's readings of true voltage ``v`` and current ``i`` (vectorised
    :meth:`NoiseModel.voltage` and :meth:`NoiseModel.current`)."""
    dv = np.diff(v, prepend=v[0])
    dvdt = dv / np.maximum(np.diff(t, prepend=t[0] - 1.0), 1e-9)
    sigma = nm.voltage_white_V + nm.voltage_per_amp_V * np.abs(i)
    slew = np.clip(dvdt * nm.sample_jitter_s * rng.standard_normal(v.size), -np.abs(dv), np.abs(dv))
    vv = v + sigma * rng.standard_normal(v.size) + slew
    vv = np.round(vv / nm.voltage_quantum_V) * nm.voltage_quantum_V
    ii = i + nm.current_white_A * rng.standard_normal(i.size)
    ii = np.round(ii / nm.current_quantum_A) * nm.current_quantum_A
    return vv, ii


def make_case(
    path: Path, prof: Profile, cause: str | None, values: dict[str, float], seed: int, ambient_c: float = AMBIENT_C
) -> str:
    """Simulate the truth on ``prof`` at ``ambient_c`` [°C] (cell and ambient), add the virtual noise, write a BDF
    CSV; its path."""
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData

    truth = battlab.Cell.load(CELL)
    if cause is not None:
        truth = truth.with_extension(cause, **values)
    res = battlab.simulate(truth, prof, soc0=SOC0, ambient=273.15 + ambient_c)
    if res.ended_by is not None:
        raise RuntimeError(f"the truth stops early ({res.ended_by}) at {ambient_c:g} degC with {cause} {values}")
    rng = np.random.default_rng(seed)
    v, i = noisy(np.asarray(res.voltage), prof.current, prof.t, rng, NoiseModel())
    cols = {TIME: prof.t, VOLTAGE: v, CURRENT: i, AMBIENT: np.full(prof.t.size, ambient_c)}
    return str(write_bdf_csv(LoggedData(path.name.split(".")[0], cols, {"soc0": SOC0}), path))


def outcome(summary: dict[str, Any], truth: str | None) -> str:
    """The diagnosis's answer: a cause; "cannot tell" when it names none but says the data cannot decide (noise
    only: any ``cannot_tell`` entry; a hidden cause: that cause among ``cannot_tell``, ``untestable`` or
    ``undetectable``); else "null"."""
    if summary.get("cause"):
        return str(summary["cause"])
    told = {k for c in summary.get("cannot_tell", []) for k in c.get("causes", [c["cause"]])}
    if truth is None:
        return "cannot tell" if told else "null"
    told |= {c["cause"] for c in (*summary.get("untestable", []), *summary.get("undetectable", []))}
    return "cannot tell" if truth in told else "null"


def run_case(
    workdir: Path,
    prof: Profile,
    k: int,
    cause: str | None,
    values: dict[str, float],
    seed: int,
    ambients: Sequence[float] = (AMBIENT_C,),
) -> dict[str, Any]:
    """One case: the truth at each of ``ambients`` [°C] (one file each, the last held out; one file: its final
    30 %), diagnosed with the true cause also fitted on the diagnosis's terms (the oracle, :func:`visible`)."""
    from battlab.diagnose.workflow import DiagnoseOptions, diagnose

    paths = [
        make_case(workdir / f"case{k}_{a:g}C.bdf.csv", prof, cause, values, seed + 100_000 * j, a)
        for j, a in enumerate(ambients)
    ]
    t0 = time.perf_counter()
    rep = diagnose(DiagnoseOptions(paths, CELL, also_fit=[cause] if cause else ()))
    sec = time.perf_counter() - t0
    s = rep.summary
    g = s["extension_gain"]
    gain = None
    if s["cause"] and g.get("rmse_after_mV") is not None and g["rmse_before_mV"] > 0:
        gain = 1.0 - g["rmse_after_mV"] / g["rmse_before_mV"]
    oracle = s.get("also_fitted", [None])[0]
    return {
        "case": k,
        "truth": cause or "null",
        "ambients": list(ambients),
        "values": values,
        "seed": seed,
        "outcome": outcome(s, cause),
        "cannot_tell": s.get("cannot_tell", []),
        "untestable": [c["cause"] for c in s.get("untestable", [])],
        "undetectable": [c["cause"] for c in s.get("undetectable", [])],
        "detectable_size": s.get("detectable_size", {}).get(cause or "", {}),
        "ranking": [(r["cause"], r["p_value"], r["passes"], r["projected"]) for r in s["ranking"]],
        "threshold": s["threshold"]["p_value"],
        "s2": s["residual"]["s2"],
        "rmse_mV": s["residual"]["rmse_mV"],
        "held_out_gain": gain,
        "oracle_gain": None if oracle is None else oracle["gain"],
        "oracle_rmse_mV": None if oracle is None else (oracle["rmse_base_mV"], oracle["rmse_held_out_mV"]),
        "rmse_before_mV": g["rmse_before_mV"],
        "rmse_after_mV": g.get("rmse_after_mV"),
        "confirmations": [(c["cause"], c["rmse_held_out_mV"]) for c in s["confirmations"]],
        "verdict": s["verdict"],
        "seconds": sec,
    }


def label(r: dict[str, Any]) -> str:
    """The table row of a case: its true cause, and for a thermal case at one ambient ``thermal@1T``."""
    amb = r.get("ambients", [AMBIENT_C])
    return f"{r['truth']}@1T" if r["truth"] == "thermal" and len(set(amb)) == 1 else r["truth"]


def visible(r: dict[str, Any]) -> bool | None:
    """Whether the hidden effect is visible on the case's data: the oracle (the true extension fitted on the training
    part with the same base parameters, start and optimiser as the diagnosis's base fit) passes the naming rule,
    a held-out RMSE gain of at least ``MIN_GAIN`` over that base fit. None: a null case or no oracle."""
    from battlab.diagnose.workflow import MIN_GAIN

    g = r.get("oracle_gain")
    return None if r["truth"] == "null" or g is None else bool(g >= MIN_GAIN)


def right_by_visibility(r: dict[str, Any]) -> bool:
    """Visible: the true cause named; invisible: no wrong cause (cannot tell naming it, null, or the true cause)."""
    if visible(r):
        return r["outcome"] == r["truth"]
    return r["outcome"] in (r["truth"], "cannot tell", "null")


def table(rows: list[dict[str, Any]]) -> str:
    """The confusion table (true cause × outcome, counts), the visibility table (per true cause: visible cases named
    right, invisible cases answered without a wrong cause), and both headline rates."""
    if not rows:
        return "no cases"
    order = [*CAUSES[:2], "thermal", "thermal@1T", *CAUSES[3:], "null"]
    truths = [c for c in order if any(label(r) == c for r in rows)]
    cols = [*CAUSES, "null", "cannot tell"]
    short = {c: c[:8] for c in cols}
    w = max(len(c) for c in truths) + 2
    out = ["true \\ named".ljust(w) + " ".join(f"{short[c]:>8}" for c in cols) + "   right"]
    for tr in truths:
        rs = [r for r in rows if label(r) == tr]
        counts = [sum(r["outcome"] == c for r in rs) for c in cols]
        right = sum(r["outcome"] == r["truth"] for r in rs)
        out.append(tr.ljust(w) + " ".join(f"{n:>8d}" for n in counts) + f"   {right}/{len(rs)}")
    hidden = [r for r in rows if r["truth"] != "null"]
    nulls = [r for r in rows if r["truth"] == "null"]
    right = sum(r["outcome"] == r["truth"] for r in hidden)
    wrong = sum(r["outcome"] not in (r["truth"], "null", "cannot tell") for r in hidden)
    ct = sum(r["outcome"] == "cannot tell" for r in hidden)
    out.append("")
    if hidden:
        out.append(
            f"hidden-effect cases: {len(hidden)}; STRICT: cause named right {right} "
            f"({100 * right / len(hidden):.0f} %), "
            f"a wrong cause {wrong}, cannot tell {ct}, null {len(hidden) - right - wrong - ct}"
        )
        out += ["", "visibility (oracle: the true extension fitted on the diagnosis's terms, held-out gain >= 30 %):"]
        out.append(
            "true cause".ljust(w)
            + "visible  named right   invisible  cannot tell  null  named right  not right   right"
        )
        for tr in [c for c in truths if c != "null"]:
            rs = [r for r in hidden if label(r) == tr]
            vis = [r for r in rs if visible(r)]
            inv = [r for r in rs if not visible(r)]
            n_ok = sum(right_by_visibility(r) for r in rs)
            out.append(
                tr.ljust(w)
                + f"{len(vis):>7d} {sum(r['outcome'] == r['truth'] for r in vis):>12d} {len(inv):>11d}"
                + f" {sum(r['outcome'] == 'cannot tell' for r in inv):>12d}"
                + f" {sum(r['outcome'] == 'null' for r in inv):>5d}"
                + f" {sum(r['outcome'] == r['truth'] for r in inv):>12d}"
                + f" {len(rs) - n_ok:>10d}   {n_ok}/{len(rs)}"
            )
        vr = sum(right_by_visibility(r) for r in hidden)
        nv = sum(bool(visible(r)) for r in hidden)
        nvr = sum(bool(visible(r)) and r["outcome"] == r["truth"] for r in hidden)
        out.append(
            f"VISIBILITY-SCORED: right {vr}/{len(hidden)} ({100 * vr / len(hidden):.0f} %); visible {nv}, of which "
            f"named right {nvr}; invisible {len(hidden) - nv}, answered without a wrong cause "
            f"{vr - nvr}"
        )
        out.append("oracle held-out gain per case (case, truth, gain, outcome):")
        out += [
            f"  {r['case']:3d} {label(r):<20} "
            + (f"{100 * r['oracle_gain']:6.1f} %" if r.get("oracle_gain") is not None else "     -  ")
            + f"  {r['outcome']}"
            for r in hidden
        ]
    if nulls:
        fa = sum(r["outcome"] not in ("null", "cannot tell") for r in nulls)
        ctn = sum(r["outcome"] == "cannot tell" for r in nulls)
        out.append(
            f"null cases: {len(nulls)}; a cause named in {fa} ({100 * fa / len(nulls):.0f} %), cannot tell {ctn}"
        )
    gains = [(r["case"], label(r), r["outcome"], r["held_out_gain"]) for r in rows if r["held_out_gain"] is not None]
    if gains:
        out.append("held-out RMSE gain of the named extension (case, truth, named, gain):")
        out += [f"  {k:3d} {t:<20} {n:<20} {100 * g:5.1f} %" for k, t, n, g in gains]
        out.append(f"  named with gain >= 30 %: {sum(g >= 0.3 for *_, g in gains)}/{len(gains)}")
    secs = np.array([r["seconds"] for r in rows])
    if secs.size:
        out.append(
            f"time per diagnosis: median {np.median(secs):.0f} s, max {secs.max():.0f} s, total {secs.sum():.0f} s"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=24, help="hidden-effect cases (cause k %% 8 of the catalog)")
    ap.add_argument("--nulls", type=int, default=10, help="noise-only cases")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--profile", choices=("drive", "rich"), default="rich")
    ap.add_argument("--causes", default=",".join(CAUSES), help="comma-separated subset of the catalog to draw from")
    ap.add_argument(
        "--thermal-ambients",
        default=",".join(f"{a:g}" for a in THERMAL_AMBIENTS_C),
        help="ambients [degC] of a thermal case's files, the last held out",
    )
    ap.add_argument(
        "--one-ambient-thermal", type=int, default=1, help="extra thermal cases at 25 degC only (cannot-tell check)"
    )
    ap.add_argument("--json", type=Path, help="save every case's result here")
    ap.add_argument("--timing", action="store_true", help="also time one diagnosis of 4 h at 1 s (a null case)")
    args = ap.parse_args(argv)
    causes = [c.strip() for c in args.causes.split(",") if c.strip()]
    bad = [c for c in causes if c not in CAUSES]
    if bad:
        print(f"--causes: unknown cause {bad[0]!r}; expected some of {', '.join(CAUSES)}", file=sys.stderr)
        return 2
    try:
        thermal_amb = tuple(float(a) for a in args.thermal_ambients.split(","))
    except ValueError:
        print(f"--thermal-ambients: expected numbers [degC] separated by commas, got {args.thermal_ambients!r}")
        return 2
    q = float(battlab.Cell.load(CELL)["Q_nom"])
    prof = profile(args.profile, q)
    rng = np.random.default_rng(args.seed)
    plan: list[tuple[str | None, dict[str, float], tuple[float, ...]]] = []
    for k in range(args.cases):
        c = causes[k % len(causes)]
        plan.append((c, SIZES[c][0](rng), thermal_amb if c == "thermal" else (AMBIENT_C,)))
    thermal_values = [v for c, v, _ in plan if c == "thermal"] or [SIZES["thermal"][0](rng)]
    for j in range(args.one_ambient_thermal if "thermal" in causes else 0):
        plan.append(("thermal", thermal_values[j % len(thermal_values)], (AMBIENT_C,)))
    # nulls spread among the hidden-effect cases (a run stopped early still has some of each)
    n_hidden = len(plan)
    for j in range(args.nulls):
        plan.insert(round((j + 1) * n_hidden / (args.nulls + 1)) + j, (None, {}, (AMBIENT_C,)))
    rows: list[dict[str, Any]] = []
    print(
        f"profile {args.profile}: {prof.t[-1] / 3600:.2f} h at 1 s; {n_hidden} hidden-effect + {args.nulls} null; "
        f"thermal cases at {', '.join(f'{a:g}' for a in thermal_amb)} degC (the last held out)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for k, (cause, values, ambients) in enumerate(plan):
            seed = 1000 * args.seed + k
            try:
                row = run_case(Path(tmp), prof, k, cause, values, seed, ambients)
            except Exception as exc:  # a failed case is a row of the table, not the end of the run
                row = {
                    "case": k,
                    "truth": cause or "null",
                    "ambients": list(ambients),
                    "values": values,
                    "seed": seed,
                    "outcome": "error",
                    "error": f"{type(exc).__name__}: {exc}",
                    "held_out_gain": None,
                    "seconds": 0.0,
                }
            rows.append(row)
            vals = ", ".join(f"{n}={v:.3g}" for n, v in values.items())
            og = row.get("oracle_gain")
            print(
                f"[{k:2d}] {label(row):<18} -> {row['outcome']:<18} {row['seconds']:5.0f} s"
                + (f"  oracle {100 * og:5.1f} %" if og is not None else "")
                + f"  ({vals})"
                + (f"  {row.get('error')}" if row["outcome"] == "error" else f"  {row['verdict'][:110]}"),
                flush=True,
            )
            if args.json:
                args.json.write_text(json.dumps({"profile": args.profile, "rows": rows}, indent=1, default=str))
        if args.timing:
            long = profile(args.profile, q, hours=4.0)
            path = make_case(Path(tmp) / "long.bdf.csv", long, None, {}, 10**6 + args.seed)
            from battlab.diagnose.workflow import DiagnoseOptions, diagnose

            t0 = time.perf_counter()
            rep = diagnose(DiagnoseOptions([path], CELL))
            sec = time.perf_counter() - t0
            print(f"4 h at 1 s ({long.t.size} samples): {sec:.0f} s, outcome {outcome(rep.summary, None)}")
            if args.json:
                d = json.loads(args.json.read_text()) if args.json.exists() else {"rows": rows}
                d["timing_4h_s"] = sec
                args.json.write_text(json.dumps(d, indent=1, default=str))
    print()
    print("sizes drawn per cause (source / reason):")
    for c in causes:
        print(f"  {c}: {SIZES[c][1]}")
    print()
    print(table([r for r in rows if r["outcome"] != "error"]))
    errs = [r for r in rows if r["outcome"] == "error"]
    if errs:
        print(f"{len(errs)} case(s) failed: " + "; ".join(f"{r['case']}: {r['error']}" for r in errs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
