"""The diagnosis's summary (DESIGN.md's ``summary.json`` contract, see docs/file-formats.md) and its verdict in
words, from the steps of :mod:`battlab.diagnose.workflow`: the residual, the score tests and the held-out decision."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from battlab import causes
from battlab.diagnose import testability
from battlab.diagnose.confirm import MIN_GAIN, S2_REFIT, Z_MIN
from battlab.diagnose.held_out import improvement_z

if TYPE_CHECKING:
    from battlab.diagnose.data import Prepared
    from battlab.diagnose.workflow import Decision, DiagnoseOptions, Residuals, Scores


def verdict_text(d: Decision, sc: Scores, s2: float, res: Residuals) -> str:
    """The answer in words a bench engineer reads first (never "no discrepancy" at s² ≫ 1)."""
    from battlab.diagnose.mechanisms import share_text

    v = d.verdict
    rmse = float(1e3 * np.sqrt(np.mean(res.r[np.isfinite(res.r)] ** 2)))
    if v.cause is not None and v.chosen is not None:
        names = ", ".join(v.chosen.names)
        if v.how == "refit":
            return (
                f"{v.cause}: a refit of its parameters ({names}) predicts the held-out data "
                f"{v.base.rmse_mV:.2f} → {v.chosen.held.rmse_mV:.2f} mV: refit them (battlab fit)"
            )
        return (
            f"{v.cause}: its fit ({names}) predicts the held-out data {v.base.rmse_mV:.2f} → "
            f"{v.chosen.held.rmse_mV:.2f} mV, better than the {v.baseline} by "
            f"{100 * (1 - v.chosen.held.metric / v.base.metric):.0f} % ({v.z:.1f} standard errors)"
        )
    if v.pairs:
        from battlab.diagnose.confirm import separating_experiment

        best = v.chosen.held.rmse_mV if v.chosen is not None else float("nan")
        fixes = [
            f"refit {k}'s parameters" if v.how == "refit" or causes.cause(k).extension is None else f"extend with {k}"
            for k in v.pairs[0]
        ]
        _, experiment = separating_experiment(v.untested or v.pairs[0])
        if v.untested:
            return (
                f"cannot tell {' from '.join(v.pairs[0])} on these data: {fixes[0]} predicts the held-out data "
                f"{v.base.rmse_mV:.2f} → {best:.2f} mV, but {', '.join(v.untested)} passes its score test alike and "
                f"these data cannot fit it; would tell: {experiment}"
            )
        return (
            f"cannot tell {' from '.join(v.pairs[0])} on these data: their fits predict the held-out data alike "
            f"({v.base.rmse_mV:.2f} → {best:.2f} mV), so {' or '.join(fixes)} explains it; would tell: {experiment}"
        )
    if s2 > S2_REFIT:
        share = sc.share
        return (
            f"the model misses these data: residual {rmse:.1f} mV RMSE against {noise_mV(rmse, s2):.2g} mV of noise "
            f"(s² {s2:.3g}); no single cause "
            f"explains it on held-out data; share of the residual along each cause's own directions: "
            f"{share_text(share)}"
        )
    if sc.passing:
        return (
            f"score tests passed ({', '.join(s.cause for s in sc.passing)}) but no fit beat the {v.baseline} on the "
            f"held-out data by {100 * MIN_GAIN:.0f} % and the noise margin"
        )
    return (
        f"no discrepancy beyond the noise: residual {rmse:.2f} mV RMSE against {noise_mV(rmse, s2):.2g} mV of noise "
        f"(s² {s2:.3g})"
    )


def noise_mV(rmse: float, s2: float) -> float:
    """The noise level [mV] that s² (mean square residual over the noise variance) was taken against."""
    return rmse / np.sqrt(s2) if s2 > 0 else float("nan")


def summarise(prep: Prepared, res: Residuals, sc: Scores, d: Decision, o: DiagnoseOptions) -> dict[str, Any]:
    """The summary (DESIGN.md's ``summary.json`` contract and what the report shows)."""
    from battlab.diagnose import score
    from battlab.diagnose.confirm import cannot_tell
    from battlab.diagnose.directions import TYPICAL

    white_var = float(np.mean(res.noise))  # each log's noise, measured on its own voltage
    s2_white = float(np.mean(res.r[np.isfinite(res.r)] ** 2) / max(white_var, 1e-300))
    v = d.verdict
    verdict = verdict_text(d, sc, s2_white, res)
    undecided = cannot_tell(v, d.fits)
    untestable = testability.untestable(prep.train, d.cause, 0.01 * float(prep.base["Q_nom"]))
    seen = (
        {d.cause}
        | {s.cause for s in sc.passing}
        | {k for c in undecided + untestable for k in c.get("causes", [c["cause"]])}
    )
    hidden = {s.cause: (s.projected_norm, sc.mimics.get(s.cause, [])) for s in sc.ranked}
    undetectable = testability.undetectable(sc.sizes, seen, TYPICAL, hidden)
    small = [c["cause"] for c in undetectable if "hidden_by" not in c]
    behind = [f"{c['cause']} (by {', '.join(c['hidden_by'])})" for c in undetectable if "hidden_by" in c]
    if small:
        verdict += "; too small to see on these data: " + ", ".join(small)
    if behind:
        verdict += "; hidden behind base parameters, not ruled out: " + ", ".join(behind)
    chosen = v.chosen
    gain = {
        "rmse_before_mV": v.base.rmse_mV,
        "rmse_after_mV": chosen.held.rmse_mV if chosen is not None and (d.cause or v.pairs) else None,
        "held_out": prep.held_name,
        "baseline": v.baseline,
        "rmse_cell_mV": d.cell.rmse_mV,
        "rmse_base_refit_mV": d.base_fit.held.rmse_mV if d.base_fit is not None else None,
        "rmse_before_K": v.base.rmse_K,
        "rmse_after_K": chosen.held.rmse_K if chosen is not None else None,
        "gain": (1.0 - chosen.held.metric / v.base.metric) if chosen is not None else None,
        # the baseline's held-out RMS of noise-normalised errors: each confirmation's ``held_out_metric`` against it
        "metric_before": v.base.metric,
        "z": v.z,
    }
    if chosen is not None:
        gain["cause_fitted"] = chosen.key
    return {
        "cause": d.cause,
        "how": v.how,
        "fix": (
            f"refit {', '.join(chosen.names)} (battlab fit)"
            if v.how == "refit" and chosen is not None
            else f"extend the model: battlab fit --extension {d.cause}"
            if d.cause is not None
            else None
        ),
        "cannot_tell": undecided,
        "untestable": untestable,
        "undetectable": undetectable,
        "detectable_size": sc.sizes,
        "ranking": [
            {**row, "passes": bool(s.dof > 0 and s.p_value < sc.p_threshold), "mimicked_by": sc.mimics.get(s.cause, [])}
            for row, s in zip(score.summary(sc.ranked), sc.ranked, strict=True)
        ],
        "extension_gain": gain,
        "verdict": verdict,
        "threshold": {
            "p_value": sc.p_threshold,
            "rule": f"block-variance score test per cause (its own directions, the other causes' base directions "
            f"projected out), Hotelling T² vs F, Bonferroni alpha {o.alpha:g} over {len(sc.ranked)} causes, blocks "
            f"of {sc.block_s:.0f} s; named on held-out data at a gain of {100 * MIN_GAIN:.0f} % and {Z_MIN:g} "
            "standard errors",
        },
        "indistinguishable": [[a, b, c] for a, b, c in sc.twins],
        "base_explained": sc.base_share,
        "shares": sc.share,
        "channels": {"voltage_rows": sc.ch.n_voltage, "temperature_rows": sc.ch.n_temperature},
        "white_noise_mV": 1e3 * float(np.sqrt(white_var)),
        "residual_over_noise": s2_white,
        "residual": res.analysis.summary(),
        "data": prep.files,
        "held_out": prep.held_name,
        # each fit's held-out gain over the baseline, in standard errors of the paired block test
        "confirmations": [
            {**f.confirmation.__dict__, "z_vs_baseline": improvement_z(v.base, f.held, sc.block_s)}
            for f in ([d.base_fit] if d.base_fit else []) + list(d.fits)
        ],
        "worse_than_no_fit": v.worse,
        "warnings": prep.warnings,
    }


__all__ = ["noise_mV", "summarise", "verdict_text"]
