"""``battlab diagnose`` as a function on values: :func:`diagnose` takes one :class:`DiagnoseOptions` and returns a
:class:`~battlab.diagnose.report.DiagnosisReport`: where the cell's simulation disagrees with logged data, which cause
of the catalog (:mod:`battlab.causes`) explains it, and whether its extension predicts data it was not fitted to.

1. The data are loaded, checked against the cell and split into training and held-out parts
   (:mod:`battlab.diagnose.data`), with the noise variance measured on each log's own voltage.
2. The cell is simulated on every experiment; the residual (measured − simulated) is analysed
   (:mod:`battlab.diagnose.residuals`) and drawn (:mod:`battlab.diagnose.figures`).
3. Each catalog cause is scored at its "off" value on the training part (:mod:`battlab.diagnose.directions`,
   :func:`battlab.diagnose.score.score_test`) with all 18 base parameters' directions projected out and the
   batch-means (block) variance, robust to correlated model error. A cause passes when its p-value (Hotelling's
   T² against F) is below ``alpha`` / (number of causes tested): Bonferroni. Each cause is tested on the
   directions of those of its parameters the data would detect somewhere in their search range; a cause not seen
   whose typical size lies below what the data detect is listed as ``undetectable`` with the experiment that would
   show it (:mod:`battlab.diagnose.testability`).
4. Confirmation (:mod:`battlab.diagnose.confirm`): the leading passing causes' extensions are fitted on the
   training part beside the base parameters that explain most of the residual, the base model gets the same fit;
   a cause is named only when its fitted extension's held-out RMSE is at least
   :data:`~battlab.diagnose.confirm.MIN_GAIN` below the base fit's; what the data cannot decide is said.

Progress goes to subscribers (:mod:`battlab.progress`) as ``note`` events of the task ``diagnose``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.diagnose import testability
from battlab.diagnose.confirm import (
    CONFIRM,
    MAX_CONFIRM,
    MIMICKED,
    MIN_GAIN,
    N_BASE,
    RANGE_SLACK,
    S2_REFIT,
    SOME_GAIN,
    candidates,
    cannot_tell,
    confirm,
    mimicked_by,
    named,
    refit_names,
)
from battlab.diagnose.data import (
    CAPACITY_FACTOR,
    HELD_OUT_FRACTION,
    MIN_COVERAGE,
    V_MARGIN,
    Part,
    Prepared,
    held_out_rmse,
    prepare,
    simulate_on,
    split,
)
from battlab.diagnose.report import Confirmation, DiagnosisReport
from battlab.identify.data_files import Ambient
from battlab.progress import Reporter, Subscriber
from protocols.errors import InputError

__all__ = [
    "ALPHA",
    "BLOCK_MIN_S",
    "CAPACITY_FACTOR",
    "CONFIRM",
    "HELD_OUT_FRACTION",
    "MAX_CONFIRM",
    "MIMICKED",
    "MIN_COVERAGE",
    "MIN_GAIN",
    "N_BASE",
    "N_BLOCKS",
    "RANGE_SLACK",
    "S2_REFIT",
    "SOME_GAIN",
    "V_MARGIN",
    "Confirmation",
    "DiagnoseOptions",
    "Part",
    "diagnose",
    "refit_names",
    "split",
]

#: family-wise false-alarm rate of the ranking (Bonferroni over the causes tested)
ALPHA = 0.01
#: contiguous blocks of the batch-means variance: about this many over the training part, each at least BLOCK_MIN_S
N_BLOCKS = 30
BLOCK_MIN_S = 60.0


@dataclass(frozen=True)
class DiagnoseOptions:
    """One diagnosis: ``data`` (paths), ``cell`` (a built-in name, a BPX file or a :class:`Cell`); ``held_out``: a
    path or file name among the data, or another file, to hold out; ``ambient`` [K] for data that do not log it;
    ``causes``: catalog keys to test (default :data:`battlab.diagnose.directions.DEFAULT_CAUSES`); ``also_fit``:
    causes whose extension is fitted on the same terms as a confirmation whatever the score tests say, reported in
    the summary's ``also_fitted`` (not used in the decision: an outside check of what the data can show)."""

    data: tuple[str | Path, ...]
    cell: Cell | str | Path
    held_out: str | Path | None = None
    soc0: float | None = None
    ambient: Ambient = None
    dt: float = 1.0
    fix_sign: bool = False
    causes: tuple[str, ...] | None = None
    alpha: float = ALPHA
    max_iter: int = 20
    also_fit: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        from battlab.diagnose.directions import DEFAULT_CAUSES

        object.__setattr__(self, "data", tuple(self.data))
        object.__setattr__(self, "also_fit", tuple(self.also_fit))
        if self.causes is not None:
            object.__setattr__(self, "causes", tuple(self.causes) or None)
        for c in (*(self.causes or ()), *self.also_fit):
            parameters.extension_parameters(c)
        for c in self.causes or ():
            if c not in DEFAULT_CAUSES:
                raise InputError(
                    f"cause {c!r} cannot be score-tested (its voltage is not differentiable at its off value); "
                    f"expected one of {', '.join(DEFAULT_CAUSES)}"
                )
        if self.soc0 is not None and not 0.0 <= self.soc0 <= 1.0:
            raise InputError(f"--soc0 {self.soc0:g}: a state of charge is between 0 and 1")
        if self.dt <= 0:
            raise InputError(f"--dt {self.dt:g} s: the resampling step must be positive")


@dataclass
class Residuals:
    """The cell on every experiment: times (concatenated), residual [V], current [A], SOC, noise variance [V²]."""

    t: np.ndarray
    r: np.ndarray
    current: np.ndarray
    soc: np.ndarray
    noise: np.ndarray
    analysis: Any


@dataclass
class Scores:
    """The score tests on the training part: residual r (projected off the base directions) and r_raw, base
    Jacobian J, weights w, time t, each cause's directions, the ranking and what passes, detectable sizes."""

    r: np.ndarray
    r_raw: np.ndarray
    J: np.ndarray
    w: np.ndarray
    base_share: float
    block_s: float
    sizes: dict[str, dict[str, float]]
    ranked: list[Any]
    passing: list[Any]
    twins: list[tuple[str, str, float]]
    mimics: dict[str, list[str]]
    p_threshold: float


def residual_step(prep: Prepared, fm: Any) -> Residuals:
    """Simulate the cell on all data and analyse the residual; a simulation that stops before half a data set is
    a mismatch of data and cell (one :class:`InputError`)."""
    from battlab.diagnose import residuals

    ts, rs, cur, socs, nvar = [], [], [], [], []
    offset = 0.0
    for p in prep.parts:
        e = p.experiment
        out = simulate_on(fm, e)
        n = out.voltage.size
        if n < MIN_COVERAGE * e.voltage.size:
            raise InputError(
                f"{e.name}: cell {prep.cell.name!r} stops at {100 * n / e.voltage.size:.0f} % of the data "
                f"({out.ended_by}): data and cell do not match"
            )
        if n < e.voltage.size:
            prep.warnings.append(
                f"{e.name}: the simulation stopped at {100 * n / e.voltage.size:.1f} % ({out.ended_by})"
            )
        t = e.profile.t[:n]
        ts.append(t - t[0] + offset)
        offset = float(ts[-1][-1]) + 1.0
        rs.append(e.voltage[:n] - out.voltage)
        i = e.profile.current[:n]
        cur.append(i)
        q = np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t))]) / 3600.0
        socs.append(e.soc0 + q / float(prep.base.capacity()))
        nvar.append(np.broadcast_to(np.asarray(e.variance, float), (e.voltage.size,))[:n])
    tt, rr, ii, ss, vv = (np.concatenate(x) for x in (ts, rs, cur, socs, nvar))
    analysis = residuals.analyse(tt, rr + 0.0, np.zeros_like(rr), ii, soc=ss, noise_variance=vv)
    return Residuals(tt, rr, ii, ss, vv, analysis)


def _training_columns(prep: Prepared, fm: Any, keys: Sequence[str], say: Reporter) -> tuple[list[np.ndarray], ...]:
    """Per training experiment: residual, base Jacobian, time, weights, and each cause's directions (in ``keys``
    order, dict per experiment), all cut to the shortest simulation."""
    from battlab.diagnose.directions import extension_directions

    lim = (float(prep.base["V_min"]) - V_MARGIN, float(prep.base["V_max"]) + V_MARGIN)
    r_all, J_all, t_all, w_all, S_all = [], [], [], [], []
    offset = 0.0
    for e in prep.train:
        say("note", text=f"extension directions on {e.name}")
        b = simulate_on(fm, e, parameters.NAMES)
        dirs = {
            d.cause: d
            for d in extension_directions(
                prep.base, e.profile, e.soc0, (), causes=keys, ambient=e.ambient, T0=e.T0, v_limits=lim
            )
        }
        n = min([b.voltage.size, *(d.S.shape[0] for d in dirs.values())])
        r_all.append(e.voltage[:n] - b.voltage[:n])
        J_all.append(b.sensitivities[:n])
        t = e.profile.t[:n]
        t_all.append(t - t[0] + offset)
        offset = float(t_all[-1][-1]) + 1.0
        w_all.append(1.0 / np.broadcast_to(np.asarray(e.variance, float), (e.voltage.size,))[:n])
        S_all.append({k: d.S[:n] for k, d in dirs.items()})
    return r_all, J_all, t_all, w_all, S_all


def score_step(prep: Prepared, fm: Any, o: DiagnoseOptions, say: Reporter) -> Scores:
    """Score every cause on the training part (see the module docstring, item 3)."""
    from battlab.diagnose import score
    from battlab.diagnose.directions import DEFAULT_CAUSES

    keys = tuple(o.causes or DEFAULT_CAUSES)
    r_all, J_all, t_all, w_all, S_all = _training_columns(prep, fm, keys, say)
    r, J, t, w = (np.concatenate(x) for x in (r_all, J_all, t_all, w_all))
    # the base model at its linearised best fit: what the 18 base parameters can absorb is taken out of the
    # residual (the score tests assume a fitted base, Jᵀ W r ≈ 0; the score itself is unchanged by this)
    r_raw, r = r, score.project_out(J, r[:, None], w)[:, 0]
    cost_raw = float(np.sum(w * r_raw**2))
    base_share = 1.0 - float(np.sum(w * r**2)) / cost_raw if cost_raw > 0 else 0.0
    block_s = max(BLOCK_MIN_S, float(t[-1] - t[0]) / N_BLOCKS)
    tested = [k for k in keys if all(k in s for s in S_all)]
    S_of = {k: np.concatenate([s[k] for s in S_all]) for k in tested}
    mimics = {k: mimicked_by(J, S_of[k], w, parameters.NAMES) for k in tested}
    p_threshold = o.alpha / max(len(tested), 1)
    sizes = {k: testability.detectable_sizes(k, r, J, S_of[k], w, t, p_threshold, block_s) for k in tested}
    results = [
        score.score_test(k, r, J, S_of[k][:, testability.informed_columns(k, sizes[k])], w, t, block_s=block_s)
        for k in tested
    ]
    ranked = score.rank_causes(results)
    passing = [s for s in ranked if s.dof > 0 and s.p_value < p_threshold]
    twins = score.indistinguishable(ranked, w)
    return Scores(r, r_raw, J, w, base_share, block_s, sizes, ranked, passing, twins, mimics, p_threshold)


@dataclass
class Decision:
    """What the held-out confirmation decided: the cause (or None), the base fit and the confirmations, the
    extension gain and the verdict so far."""

    cause: str | None
    base_fit: Confirmation | None
    confirmations: list[Confirmation]
    relevant: tuple[str, ...]
    gain: dict[str, Any]
    verdict: str


def decide_step(prep: Prepared, fm: Any, sc: Scores, o: DiagnoseOptions, say: Reporter) -> Decision:
    """Fit the leading passing causes and the base model on the training part; name the cause that wins on the
    held-out part by :data:`MIN_GAIN`."""
    start_rmse = held_out_rmse(fm, prep.base, prep.parts)
    relevant = refit_names(prep.base, sc.J, sc.r_raw, sc.w, parameters.NAMES)
    if not sc.passing:
        gain = {
            "rmse_before_mV": start_rmse,
            "rmse_after_mV": None,
            "held_out": prep.held_name,
            "rmse_cell_mV": start_rmse,
        }
        return Decision(None, None, [], relevant, gain, "no cause passes its score test")
    cands = [s.cause for s in candidates(sc.passing, sc.twins)]
    also_with = f" and with {', '.join(cands)}" if cands else ""
    say("note", text=f"fitting the base model's {', '.join(relevant)}{also_with} on the training part")
    base_fit, *confirmations = confirm(prep.base, [None, *cands], relevant, prep.train, prep.parts, o.max_iter)
    cause = named(base_fit, confirmations)
    best = min(confirmations, key=lambda c: c.rmse_held_out_mV)
    chosen = next(c for c in confirmations if c.cause == cause) if cause else best
    gain = {
        "rmse_before_mV": base_fit.rmse_held_out_mV,
        "rmse_after_mV": chosen.rmse_held_out_mV,
        "held_out": prep.held_name,
        "cause_fitted": chosen.cause,
        "rmse_cell_mV": start_rmse,
    }
    verdict = (
        f"{cause} passes its score test and its fitted extension lowers the held-out RMSE "
        f"{base_fit.rmse_held_out_mV:.2f} → {chosen.rmse_held_out_mV:.2f} mV"
        if cause
        else f"score tests passed ({', '.join(s.cause for s in sc.passing)}) but no fitted extension lowered the "
        f"held-out RMSE by {100 * MIN_GAIN:.0f} % against the same base fit"
    )
    return Decision(cause, base_fit, confirmations, relevant, gain, verdict)


def also_fit_step(prep: Prepared, d: Decision, o: DiagnoseOptions, say: Reporter) -> list[dict[str, Any]]:
    """The ``also_fit`` causes fitted on the same terms as a confirmation (reported, not decided on)."""
    done: dict[str | None, Confirmation] = {c.cause: c for c in d.confirmations}
    if d.base_fit is not None:
        done[None] = d.base_fit
    todo = [k for k in dict.fromkeys((None, *o.also_fit)) if k not in done]
    if todo:
        say("note", text=f"fitting {', '.join(k or 'the base model' for k in todo)} on the training part (also_fit)")
        done.update(zip(todo, confirm(prep.base, todo, d.relevant, prep.train, prep.parts, o.max_iter), strict=True))
    ref = done[None]
    return [
        {
            **done[k].__dict__,
            "rmse_base_mV": ref.rmse_held_out_mV,
            "gain": 1.0 - done[k].rmse_held_out_mV / ref.rmse_held_out_mV,
        }
        for k in o.also_fit
    ]


def summarise(prep: Prepared, res: Residuals, sc: Scores, d: Decision, o: DiagnoseOptions) -> dict[str, Any]:
    """The summary (DESIGN.md's ``summary.json`` contract and what the report shows)."""
    from battlab.diagnose import score
    from battlab.diagnose.directions import TYPICAL

    verdict = d.verdict
    white_var = float(np.mean(res.noise))  # each log's noise, measured on its own voltage
    s2_white = float(np.mean(res.r[np.isfinite(res.r)] ** 2) / max(white_var, 1e-300))
    if d.cause is None and s2_white > S2_REFIT and sc.base_share > 0.5:
        verdict += (
            f"; the residual is {s2_white:.3g} × the noise level, but {100 * sc.base_share:.0f} % of it lies along "
            "the base parameters' directions: refit them (battlab fit)"
        )
    base_rmse = d.base_fit.rmse_held_out_mV if d.base_fit else float("nan")
    undecided = cannot_tell(d.cause, d.confirmations, base_rmse, sc.ranked, sc.mimics, s2_white, sc.base_share)
    untestable = testability.untestable(prep.train, d.cause, 0.01 * float(prep.base["Q_nom"]))
    seen = {d.cause} | {s.cause for s in sc.passing} | {c["cause"] for c in undecided + untestable}
    undetectable = testability.undetectable(sc.sizes, seen, TYPICAL)
    if undetectable:
        verdict += "; too small to see on these data: " + ", ".join(c["cause"] for c in undetectable)
    if undecided:
        verdict += "; cannot tell " + ", ".join(c["cause"] for c in undecided) + " on these data"
    return {
        "cause": d.cause,
        "cannot_tell": undecided,
        "untestable": untestable,
        "undetectable": undetectable,
        "detectable_size": sc.sizes,
        "ranking": [
            {**row, "passes": bool(s.dof > 0 and s.p_value < sc.p_threshold), "mimicked_by": sc.mimics[s.cause]}
            for row, s in zip(score.summary(sc.ranked), sc.ranked, strict=True)
        ],
        "extension_gain": d.gain,
        "verdict": verdict,
        "threshold": {
            "p_value": sc.p_threshold,
            "rule": f"block-variance score test, Hotelling T² vs F, Bonferroni alpha {o.alpha:g} over "
            f"{len(sc.ranked)} causes, blocks of {sc.block_s:.0f} s",
        },
        "indistinguishable": [[a, b, c] for a, b, c in sc.twins],
        "base_explained": sc.base_share,
        "white_noise_mV": 1e3 * float(np.sqrt(white_var)),
        "residual_over_noise": s2_white,
        "residual": res.analysis.summary(),
        "data": prep.files,
        "held_out": prep.held_name,
        "confirmations": [c.__dict__ for c in ([d.base_fit] if d.base_fit else []) + d.confirmations],
        "warnings": prep.warnings,
    }


def diagnose(options: DiagnoseOptions, subscribers: Sequence[Subscriber] = ()) -> DiagnosisReport:
    """Diagnose the cell on logged data (see :class:`DiagnoseOptions` and the module docstring)."""
    from battlab.identify.forward import ForwardModel

    o = options
    t_start = time.perf_counter()
    say = Reporter("diagnose", subscribers)
    cell = o.cell if isinstance(o.cell, Cell) else Cell.load(o.cell)
    prep = prepare(o.data, cell, held_out=o.held_out, soc0=o.soc0, ambient=o.ambient, dt=o.dt, fix_sign=o.fix_sign)
    say("note", text="simulating the cell on the data")
    fm = ForwardModel(prep.base, v_margin=V_MARGIN)
    res = residual_step(prep, fm)
    sc = score_step(prep, fm, o, say)
    d = decide_step(prep, fm, sc, o, say)
    summary = summarise(prep, res, sc, d, o)
    if o.also_fit:
        summary["also_fitted"] = also_fit_step(prep, d, o, say)
    summary["seconds"] = time.perf_counter() - t_start
    return DiagnosisReport(summary, res.analysis, sc.ranked, d.confirmations, d.base_fit, cell.name, prep.warnings)
