"""The one machine-readable summary of a cumulative fit (``battlab fit``'s ``summary.json``, the campaign's fit
stages), with how far each interval can be trusted.

An interval (eq. 46) is a statement about noise around a converged fit of a model that explains its data. It is
marked ``trusted: false`` with the reasons when that does not hold: the fit did not converge, the statistics are
invalid, the parameter is set-identified (only its invariant τ, κ or ρ is: its interval is an orbit), it sits at a
bound (one-sided) or its interval runs to one (the data do not inform it there), s² shows model error (then the
interval scaled by s², ``ci95_scaled``, is given), or the residual is correlated from sample to sample (model error
that s² may not show); an invariant also when a parameter of its electrode's orbit sits at a bound.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any

from battlab import parameters
from battlab.identify.fit import FitResult
from battlab.identify.statistics import Estimate, Statistics
from battlab.identify.symmetry import INVARIANTS, ORBITS, bounds_range

#: s² above this: the weighted residual is model error, not the noise the weights assume (at N ≈ 10⁴ samples the
#: sampling spread of s² is about ±0.02, so 2 is far outside it)
S2_MODEL_ERROR = 2.0
#: lag-1 autocorrelation of the weighted residual above this (and above :data:`AUTOCORRELATION_Z` standard errors of
#: white noise, 1/√n): the residual holds a part the model cannot follow, about ρ/(1−ρ) of the noise variance, and
#: the fit has absorbed some of it into its parameters. Eq. 46 assumes white noise; the intervals are then too narrow
#: and may be biased, and no s² scaling repairs a bias. It complements s², which compares the residual with the noise
#: model (itself an estimate): the correlation compares the residual with itself.
AUTOCORRELATION_MODEL_ERROR = 0.05
AUTOCORRELATION_Z = 4.0
#: θ̄ this close to 0 or 1 counts as reaching the bound
AT_EDGE = 1e-3


def stages_text(done: int, total: int) -> str:
    """``"stage 1 of 4"``, ``"stages 1–3 of 4"``, or with no stage done ``"equilibrium only (stages 0 of 4)"`` (the
    only result written before stage 1 is the equilibrium fit's)."""
    if done == 0:
        return f"equilibrium only (stages 0 of {total})"
    return f"stage 1 of {total}" if done == 1 else f"stages 1–{done} of {total}"


def fit_caveats(converged: bool, st: Statistics, autocorrelation: tuple[float, int] = (math.nan, 0)) -> list[str]:
    """Why no interval of this fit can be trusted as it stands (empty: the fit's own conditions hold).
    ``autocorrelation``: the residual's lag-1 autocorrelation and its number of pairs (:class:`FitResult`)."""
    out = []
    if not converged:
        out.append("the fit did not converge")
    if st.s2 == st.s2 and st.s2 > S2_MODEL_ERROR:
        out.append(f"s² = {st.s2:.3g} > {S2_MODEL_ERROR:g}: the residual is model error, not noise (use ci95_scaled)")
    rho, n = autocorrelation
    if n > 0 and rho > AUTOCORRELATION_MODEL_ERROR and rho * math.sqrt(n) > AUTOCORRELATION_Z:
        out.append(
            f"the residual is correlated from sample to sample (lag-1 autocorrelation {rho:.2f}; white noise: "
            f"0 ± {1 / math.sqrt(n):.2g}): part of it is model error the fit absorbed, so the intervals are too "
            "narrow and may be biased"
        )
    return out


def estimate_caveats(e: Estimate) -> list[str]:
    """Why this parameter's interval cannot be trusted, beyond the fit's own caveats."""
    out = []
    if e.set_identified:
        out.append("set-identified: the data fix only its invariant (τ, κ or ρ); the interval is the symmetry orbit's")
    elif not e.identifiable or e.ci95 is None:
        out.append("not identifiable from these data")
    if e.at_bound:
        out.append(f"at its {e.at_bound} bound (one-sided interval)")
    elif e.ci95 is not None and not e.set_identified:
        spec = parameters.spec(e.name)
        lo, hi = (spec.normalise(v) if v > 0 or spec.scale.value == "linear" else 0.0 for v in e.ci95)
        if lo <= AT_EDGE or hi >= 1.0 - AT_EDGE:
            out.append("its interval runs to a bound: the data do not inform it there")
    return out


def parameter_entry(e: Estimate, caveats: Sequence[str]) -> dict[str, Any]:
    why = [*caveats, *estimate_caveats(e)]
    return {
        "value": e.value,
        "ci95": list(e.ci95) if e.ci95 else [None, None],
        "ci95_scaled": list(e.ci95_scaled) if e.ci95_scaled else None,
        "at_bound": e.at_bound is not None,
        "bound": e.at_bound,
        "identifiable": e.identifiable,
        "set_identified": e.set_identified,
        "theta_bar": e.theta_bar,
        "trusted": not why,
        "untrusted_because": why,
    }


def invariant_caveats(name: str, ci95: tuple[float, float], estimates: Sequence[Estimate]) -> list[str]:
    """Why an invariant's interval cannot be trusted, beyond the fit's own caveats: a parameter of its electrode's
    orbit sits at a bound (the orbit is cut there: for a factor of the invariant the delta-method interval moves only
    with the free factors, e.g. κ = k/R_s with k held at its bound varies as 1/R_s alone; for the others, what the
    bound denies is put into them: with k_n held at its bound ρ_n came out 2.9 × its truth, its interval 1.4 % wide,
    ``tests/battlab/identify/test_identify_symmetry.py``), or the interval runs to the range the bounds allow."""
    powers = next(inv[name] for inv in INVARIANTS.values() if name in inv)
    orbit = next(o for o in ORBITS.values() if set(powers) <= set(o))
    by = {e.name: e for e in estimates}
    out = [
        f"{n} at its {by[n].at_bound} bound: the interval is conditional on it"
        for n in orbit
        if n in by and by[n].at_bound
    ]
    lo, hi = bounds_range(powers)
    if ci95[0] <= lo * (1 + AT_EDGE) or ci95[1] >= hi * (1 - AT_EDGE):
        out.append("its interval runs to the range the bounds allow: the data do not inform it there")
    return out


def invariant_entries(st: Statistics, caveats: Sequence[str]) -> dict[str, dict[str, Any]]:
    out = {}
    for i in st.invariants:
        why = [*caveats, *invariant_caveats(i.name, i.ci95, st.estimates)]
        out[i.name] = {
            "value": i.value,
            "ci95": list(i.ci95),
            "definition": i.definition,
            "trusted": not why,
            "untrusted_because": why,
        }
    return out


def dynamic_summary(results: Sequence[FitResult], total: int, base: dict[str, Any] | None = None) -> dict[str, Any]:
    """The summary after the finished stages ``results`` of ``total`` (partial until the last), on top of ``base``
    (e.g. the equilibrium fit's entries, which a dynamic fit keeps)."""
    out = copy.deepcopy(base) if base else {"parameters": {}, "rmse_mV": {}, "converged": True}
    last = results[-1]
    st = last.statistics
    partial = len(results) < total
    # the result and its intervals are the last stage's, at its end point (it refits every earlier stage's
    # parameters): an earlier stage that stopped at its limit only gave it its start
    converged = bool(out.get("converged", True) and last.convergence.converged and not partial)
    caveats = fit_caveats(last.convergence.converged, st, last.autocorrelation)
    if not st.valid:
        caveats.append(f"invalid statistics: {st.reason}")
    for e in st.estimates:
        out["parameters"][e.name] = parameter_entry(e, caveats)
    out["invariants"] = invariant_entries(st, caveats)
    out["rmse_mV"] = {**out.get("rmse_mV", {}), **last.rmse_mV}
    out["rmse_before_mV"] = dict(results[0].rmse_before_mV)
    out["s2"] = st.s2
    out["converged"] = converged
    out["partial"] = partial
    out["status"] = ("partial: " if partial else "complete: ") + stages_text(len(results), total)
    out["stages_done"], out["stages_total"] = len(results), total
    out["stages"] = [r.report() for r in results]
    if "soc0" in last.extra:  # start SOCs fitted per experiment (a nuisance the statistics are marginal over)
        out["start_soc"] = {k: float(v) for k, v in last.extra["soc0"].items()}
    held = [e.name for e in st.estimates if e.name not in last.names]
    if held:
        out["held"] = {e.name: e.value for e in st.estimates if e.name in held}
    trusted = [n for n, p in out["parameters"].items() if p.get("trusted")]
    out["trust"] = {
        "caveats": caveats,
        "trusted": trusted,
        "untrusted": [n for n, p in out["parameters"].items() if p.get("trusted") is False],
    }
    return out


def equilibrium_only(base: dict[str, Any], total: int) -> dict[str, Any]:
    """The summary of the equilibrium fit alone: partial, none of ``total`` stages done, or (``total`` 0: no dynamic
    stage follows) complete."""
    out = copy.deepcopy(base)
    partial = total > 0
    status = "partial: " + stages_text(0, total) if partial else "complete: equilibrium only"
    converged = bool(out["converged"]) and not partial
    out.update(partial=partial, status=status, stages_done=0, stages_total=total, converged=converged, stages=[])
    return out


__all__ = [
    "AUTOCORRELATION_MODEL_ERROR",
    "AUTOCORRELATION_Z",
    "S2_MODEL_ERROR",
    "dynamic_summary",
    "equilibrium_only",
    "estimate_caveats",
    "fit_caveats",
    "invariant_caveats",
    "invariant_entries",
    "parameter_entry",
    "stages_text",
]
