"""Dynamic identification: weighted least squares (eq. 41, squared) by Levenberg–Marquardt-type iterations
(eqs. 42–43) with the model's exact sensitivities as the Jacobian, in normalised coordinates θ̄ ∈ [0, 1].

The residual of experiment i at sample k is r = (y_i(k) − ŷ_i(k; θ̄)) / √Q_i (W = Q⁻¹); scipy's
``least_squares`` (trust-region reflective, bounds [0, 1], Jacobian scaling as eq. 42's diag term) drives the
iteration; the Jacobian is ours: −dV/dθ̄ / √Q from the forward sensitivities (:mod:`battlab.identify.problem`). A
simulation that stops early at a voltage limit holds its last voltage for the missing samples (their Jacobian rows
are zero), so a bad trial point costs much instead of failing.

Group-wise and cumulative (docs/decisions.md): stage k fits the parameters of groups 1..k on all data of stages
1..k, starting where stage k − 1 ended; the final intervals are the last stage's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from battlab import parameters
from battlab.cell import Cell
from battlab.identify import statistics
from battlab.identify.ageing import Ageing
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from battlab.identify.gauss_newton import GaussNewtonStep, bounded_gauss_newton
from battlab.identify.problem import Problem, abs_errors_mV, residual_autocorrelation, rmse_mV
from battlab.specs import Scale
from battlab.threads import cores
from protocols.errors import InputError

#: The paper's Table 9 groups (the design module's groups replace them when a plan gives its own).
TABLE9_GROUPS = parameters.TABLE9_GROUPS


@dataclass(frozen=True)
class Options:
    """Stopping rule and bound handling (the same for the OED and the conventional fits)."""

    max_nfev: int = 40
    #: Relative cost change: with cost ≈ N/2 ≈ 10⁴ a change of 1e-6 is 0.01 χ² units, far below one σ of any
    #: parameter; tighter tolerances only make the (linearly converging, large-residual) early stages crawl.
    ftol: float = 1e-6
    xtol: float = 1e-6
    gtol: float = 1e-8
    bound_tol: float = 1e-3  # θ̄ this close to 0 or 1 counts as at the bound
    rcond: float = statistics.RCOND
    #: Threads that simulate the experiments of one evaluation in parallel (None: one per core; the compiled
    #: stepper releases the GIL). Results do not depend on it.
    workers: int | None = None
    #: Simulations for Gauss–Newton steps after an optimiser stopped by its iteration limit (see :func:`_polish`),
    #: taken out of ``max_nfev`` (the optimiser keeps at least its first evaluation); 0: none.
    polish: int = 8
    #: Also converged (when the optimiser stopped on its iteration limit) if the linearised model predicts at
    #: most this cost decrease [½χ² units] inside the bounds: 0.005 means within 0.1 σ of the minimum. (Where
    #: the optimiser met its tolerances the prediction is reported only: along the curved valleys of nearly
    #: dependent parameters the linearisation holds for steps of about 1e-3 in θ̄.)
    predicted_tol: float = 5e-3
    #: Also fit the logged surface temperature where the data have it (rows weighted by its own noise level)
    temperature: bool = False
    #: How far [θ̄] the search box of each of the 18 base parameters reaches beyond its built-in range on either side
    #: (:func:`search_box`): 0 for the paper's identification; a diagnosis of another cell asks where that cell
    #: differs from its file, which need not lie inside the paper cell's ranges
    widen: float = 0.0


@dataclass(frozen=True)
class Convergence:
    """How the iteration ended."""

    converged: bool
    reason: str
    iterations: int  # function evaluations (one simulation of all experiments each)
    jacobian_evaluations: int
    cost_start: float  # ½ Σ r² at the start
    cost: float  # ½ Σ r² at the end
    gradient_norm: float  # ‖Jᵀr‖∞ projected on the bounds (scipy's first-order optimality)
    seconds: float
    #: Cost decrease that the bounded Gauss–Newton step from the end point predicts (linearised model); NaN when
    #: that step could not be computed (the optimiser failed, or the step did: ``reason`` says which)
    predicted_decrease: float = float("nan")


@dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted cell, its statistics, convergence report and error CDF data (one stage)."""

    cell: Cell
    names: tuple[str, ...]
    theta_bar: np.ndarray
    statistics: statistics.Statistics
    convergence: Convergence
    rmse_mV: dict[str, float]
    rmse_before_mV: dict[str, float]
    errors_before_mV: np.ndarray  # |y − ŷ| at the start point, all samples used
    errors_after_mV: np.ndarray
    experiments: tuple[str, ...] = ()
    stage: int = 1
    extra: dict[str, object] = field(default_factory=dict)
    #: per experiment the noise level its weights assume [mV] (√ of the mean variance): the RMSE's yardstick
    noise_mV: dict[str, float] = field(default_factory=dict)
    #: lag-1 autocorrelation of the weighted residual at the solution and its number of sample pairs
    #: (:func:`battlab.identify.problem.residual_autocorrelation`): ≈ 0 when the residual is the noise
    autocorrelation: tuple[float, int] = (float("nan"), 0)

    def report(self) -> dict[str, object]:
        """A JSON-able fit report (parameters, intervals, convergence, RMSEs)."""
        st = self.statistics
        c = self.convergence
        return {
            "stage": self.stage,
            "parameters": list(self.names),
            "experiments": list(self.experiments),
            "converged": c.converged,
            "reason": c.reason,
            "iterations": c.iterations,
            "cost_start": c.cost_start,
            "cost": c.cost,
            "gradient_norm": c.gradient_norm,
            "predicted_decrease": c.predicted_decrease,
            "seconds": c.seconds,
            "statistics_valid": st.valid,
            "statistics_note": st.reason,
            # held radii moved along their orbits (R_s / its start value) where a bound held the first fit
            "reseated": dict(self.extra.get("reseated", {})),
            "s2": st.s2,
            "residual_autocorrelation": self.autocorrelation[0] if np.isfinite(self.autocorrelation[0]) else None,
            "condition": st.condition,
            "not_identifiable": list(st.unidentifiable),
            "null_space": [dict(d) for d in st.null_space],
            "correlation": _nan_to_none(
                st.correlation if st.correlation is not None else statistics.correlation(st.covariance_identifiable)
            ),
            "rmse_mV": self.rmse_mV,
            "rmse_before_mV": self.rmse_before_mV,
            "noise_mV": self.noise_mV,
            "estimates": {
                e.name: {
                    "value": e.value,
                    "ci95": list(e.ci95) if e.ci95 else None,
                    "ci95_scaled": list(e.ci95_scaled) if e.ci95_scaled else None,
                    "sigma": e.sigma,
                    "at_bound": e.at_bound,
                    "identifiable": e.identifiable,
                    "set_identified": e.set_identified,
                }
                for e in st.estimates
            },
            "invariants": {
                i.name: {"value": i.value, "ci95": list(i.ci95), "definition": i.definition} for i in st.invariants
            },
        }


def _nan_to_none(a: np.ndarray | None) -> list[list[float | None]] | None:
    if a is None:
        return None
    return [[float(v) if np.isfinite(v) else None for v in row] for row in np.asarray(a, float)]


POLISH_STEPS = (1.0, 0.5, 0.25, 0.1, 0.03, 0.01)

#: a porosity is held this far [1] below the one that fills an electrode (ε_s + ε_e < 1)
EPS_MARGIN = 1e-3


#: the search box of a parameter whose start value lies outside the built-in range (eq. 1's bounds, the paper cell's)
#: reaches this far [θ̄] beyond that value, so a fit of another cell neither starts clipped to a bound nor is held there
REACH = 0.5
#: a positive quantity's search box stops at this fraction of its built-in lower bound (a diffusivity or conductivity
#: scale of 0 is no cell)
FLOOR = 0.1


def search_box(cell: Cell, names: Sequence[str], widen: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper bounds of each fitted parameter in θ̄.

    The built-in range [0, 1], widened by ``widen`` on either side for the 18 base parameters (:attr:`Options.widen`).
    A parameter the start ``cell`` holds outside it (a BPX cell's rate constants two decades below the paper cell's)
    gets the box extended to hold its value with :data:`REACH` beyond it: the cell's own value is the best prior, and
    a fit that started clipped to the range would start from another cell. A linearly scaled quantity with a
    non-negative range stays non-negative (one with a positive range above :data:`FLOOR` of its lower bound, unless
    the cell holds less), and where the physical region ends inside the box (an electrolyte volume fraction ε_e± must
    leave room for the cell's active material: ε_s + ε_e < 1) the bound is the physical one, so a fit is held inside
    it by its parameterisation instead of failing on an impossible cell."""
    lower, upper = np.zeros(len(names)), np.ones(len(names))
    for k, n in enumerate(names):
        spec = parameters.spec(n)
        th = float(cell.normalised(n))
        w = widen if n in parameters.NAMES else 0.0
        lo, hi = -w, 1.0 + w
        lo, hi = (th - REACH if th < lo else lo), (th + REACH if th > hi else hi)
        if spec.scale is Scale.LINEAR and spec.lower >= 0.0:
            lo = max(lo, min(th, spec.normalise(FLOOR * spec.lower)))
        if n in ("eps_e_n", "eps_e_p"):
            cap = 1.0 - float(cell[f"eps_s_{n[-1]}"]) - EPS_MARGIN
            hi = float(np.clip(spec.normalise(cap), lo + 1e-3, hi))
        lower[k], upper[k] = lo, hi
    return lower, upper


def _polish(prob: Problem, x: np.ndarray, opt: Options) -> tuple[np.ndarray, GaussNewtonStep, int]:
    """Bounded Gauss–Newton steps with backtracking after an optimiser stopped by its iteration limit (the
    trust-region iterations crawl along the long, curved valleys of the nearly dependent parameters).

    Stops when the linearised cost predicts a decrease below ``opt.predicted_tol`` inside the bounds, when no
    fraction in :data:`POLISH_STEPS` of the step lowers the cost, when the step cannot be computed
    (:attr:`GaussNewtonStep.failed`) or after ``opt.polish`` simulations; returns (x, the Gauss–Newton step from x
    with its predicted decrease, simulations used).
    """
    r, J, _ = prob.evaluate(x)
    cost = 0.5 * float(r @ r)
    gn = bounded_gauss_newton(x, J, r, prob.upper, prob.lower)
    used = 0
    while gn.failed is None and gn.predicted > opt.predicted_tol and used < opt.polish:
        for a in POLISH_STEPS[: opt.polish - used]:
            xt = np.clip(x + a * gn.step, prob.lower, prob.upper)
            rt = prob.evaluate(xt)[0]
            used += 1
            ct = 0.5 * float(rt @ rt)
            if ct < cost:
                break
        else:
            break
        x, cost = xt, ct
        r, J, _ = prob.evaluate(x)
        gn = bounded_gauss_newton(x, J, r, prob.upper, prob.lower)
    return x, gn, used


def fit(
    cell: Cell,
    experiments: Sequence[Experiment],
    names: Sequence[str],
    *,
    options: Options | None = None,
    forward: ForwardModel | None = None,
    start: Cell | None = None,
    stage: int = 1,
    soc_span: float = 0.0,
    soc_start: Mapping[str, float] | None = None,
    ageing: Ageing | None = None,
    on_evaluation: Callable[[int, float], None] | None = None,
) -> FitResult:
    """Fit the dynamic parameters ``names`` of ``cell`` to ``experiments`` (eq. 41 by LM, eqs. 42–43).

    ``start`` (default ``cell``) gives the start point; ``forward`` may be shared between fits of cells that
    differ only in dynamic values (one compiled model). ``soc_span`` > 0 adds one start-SOC nuisance parameter
    per experiment (soc0 ± ``soc_span``); the statistics of ``names`` are then marginal over them (the Jacobian
    projected off the nuisance columns) and ``extra["soc0"]`` holds the fitted start SOCs; ``soc_start`` (experiment
    name → SOC) starts them there instead of at soc0, the span still centred on soc0. A fit that stops
    without meeting the stopping rule
    returns its best point with ``convergence.converged = False`` and the reason.

    ``ageing`` (:mod:`battlab.identify.ageing`): each data file of the experiments gets its own n_Li and/or
    capacity, fitted with ``names`` (finite-difference columns); ``names``' statistics are
    marginal over them, and ``extra["ageing"]`` holds each file's values with 95 % intervals (from the covariance of
    all parameters). The fitted cell stays at the start cell's ageing state (the per-file values are relative to it).

    ``on_evaluation(k, cost)``: called after the k-th simulation of all experiments (cost ½χ²), for progress.
    """
    names = parameters.check_names(list(names))
    if not names:
        raise InputError("fit: no parameters to fit")
    if not experiments:
        raise InputError("fit: no experiments")
    opt = options or Options()
    fm = forward or ForwardModel(cell)
    start = start or cell
    theta_full = start.theta_bar()
    if len(theta_full) != len(getattr(fm, "names", theta_full)):
        raise InputError(f"fit: the start cell's extensions {list(start.extensions)} differ from the model's")
    n_workers = min(opt.workers or cores(), len(experiments)) if fm.thread_safe else 1
    pool = ThreadPoolExecutor(n_workers) if n_workers > 1 else None
    try:
        return _fit(
            cell,
            experiments,
            names,
            opt,
            fm,
            start,
            stage,
            soc_span,
            theta_full,
            pool,
            ageing,
            on_evaluation,
            soc_start,
        )
    finally:
        if pool is not None:
            pool.shutdown()


def _fit(
    cell: Cell,
    experiments: Sequence[Experiment],
    names: list[str],
    opt: Options,
    fm: ForwardModel,
    start: Cell,
    stage: int,
    soc_span: float,
    theta_full: np.ndarray,
    pool: ThreadPoolExecutor | None,
    ageing: Ageing | None = None,
    on_evaluation: Callable[[int, float], None] | None = None,
    soc_start: Mapping[str, float] | None = None,
) -> FitResult:
    prob = Problem(fm, experiments, names, theta_full, soc_span, pool, ageing, opt.temperature)
    prob.on_evaluation = on_evaluation
    lower, upper = search_box(start, names, opt.widen)
    prob.lower = np.r_[lower, np.zeros(prob.n_nuis + prob.n_age)]
    prob.upper = np.r_[upper, np.ones(prob.n_nuis + prob.n_age)]
    x0 = np.r_[
        np.clip(theta_full[prob.idx], lower + 1e-6, upper - 1e-6),
        prob.soc_x0(soc_start or {}),
        np.clip(prob.age_x0(), 0.0, 1.0),
    ]
    t0 = time.perf_counter()
    r0, _, preds0 = prob.evaluate(x0)
    cost0 = 0.5 * float(r0 @ r0)
    err = None
    # the optimiser's first evaluation (at x0) is the one above, from the cache; the polish keeps up to ``polish`` of
    # the evaluations: the optimiser's simulations and the polish's together stay within max_nfev
    reserve = min(opt.polish, opt.max_nfev - 1)
    try:
        sol = least_squares(
            lambda x: prob.evaluate(x)[0],
            x0,
            jac=lambda x: prob.evaluate(x)[1],
            bounds=(prob.lower, prob.upper),
            method="trf",
            x_scale="jac",
            ftol=opt.ftol,
            xtol=opt.xtol,
            gtol=opt.gtol,
            max_nfev=max(1, opt.max_nfev - reserve),
        )
        status, njev, opt_norm = sol.status, sol.njev, sol.optimality
    except (np.linalg.LinAlgError, ValueError) as exc:  # keep the best point seen
        err = f"optimiser failed: {exc}"
        status, njev, opt_norm = -1, 0, float("nan")
    # the best point evaluated, never a worse one than the start (the optimiser's last point may be a rejected trial,
    # and re-simulating it would cost an evaluation beyond the limit)
    assert prob.best_x is not None
    x = prob.best_x.copy()
    # polish only a fit stopped by its iteration limit (after a tolerance stop the valleys' curvature defeats it),
    # with the evaluations left
    gn_step = GaussNewtonStep(np.zeros_like(x), float("nan"))
    if err is None:
        left = max(0, opt.max_nfev - prob.n_sim)
        x, gn_step, _ = _polish(prob, x, replace(opt, polish=min(opt.polish, left) if status == 0 else 0))
    dec = gn_step.predicted
    r, J, preds = prob.evaluate(x)
    cost = 0.5 * float(r @ r)
    nfev = prob.n_sim
    reasons = {
        -1: "failed",
        0: "maximum number of iterations reached",
        1: "gradient tolerance (gtol) met",
        2: "cost change below ftol",
        3: "step below xtol",
        4: "ftol and xtol both met",
    }
    ended = f"{reasons.get(status, 'unknown')}" if err is None else err
    # a failed Gauss–Newton step predicts nothing (NaN): only the optimiser's own tolerances can then say converged
    converged = err is None and (status > 0 or (gn_step.failed is None and dec <= opt.predicted_tol))
    if gn_step.failed is not None:
        gn = f"the bounded Gauss–Newton step failed: {gn_step.failed}"
    else:
        gn = f"the linearised cost predicts a further decrease of {dec:.2g} inside the bounds"
    if err is not None:
        reason = err
    elif converged and status == 0:  # the stopping rule holds where the optimiser ran out of evaluations
        reason = f"converged: {gn} (≤ {opt.predicted_tol:g}; the optimiser stopped at its evaluation limit)"
    elif converged:
        reason = f"converged ({ended}); {gn}"
    else:
        reason = f"not converged: {ended}; {gn}" + ("" if gn_step.failed else f" (> {opt.predicted_tol:g})")
    seconds = time.perf_counter() - t0
    p = len(names)
    extra: dict[str, object] = {}
    if prob.n_nuis:
        extra["soc0"] = {e.name: prob.soc_of(i, x) for i, e in enumerate(prob.exps)}
    if prob.n_age:
        extra["ageing"] = _ageing_report(prob, x, J, r, opt)
    if prob.n_nuis or prob.n_age:
        Q, _ = np.linalg.qr(J[:, p:])
        J = J[:, :p] - Q @ (Q.T @ J[:, :p])  # marginal information of the physical parameters
        x = x[:p]
    box = (prob.lower[: len(x)], prob.upper[: len(x)])
    at_bound = [
        ("lower" if v < lo + opt.bound_tol else "upper" if v > u - opt.bound_tol else None)
        for v, lo, u in zip(x, *box, strict=True)
    ]
    st = statistics.compute(names, x, J, -r, at_bound, rcond=opt.rcond, box=box)
    th = prob.full(x)
    fitted = start.with_normalised(**{n: float(v) for n, v in zip(names, x, strict=True)})
    conv = Convergence(bool(converged), reason, int(nfev), int(njev or 0), cost0, cost, float(opt_norm), seconds, dec)
    return FitResult(
        fitted,
        names,
        th[prob.idx],
        st,
        conv,
        rmse_mV(experiments, preds),
        rmse_mV(experiments, preds0),
        abs_errors_mV(experiments, preds0),
        abs_errors_mV(experiments, preds),
        tuple(e.name for e in experiments),
        stage,
        extra,
        {e.name: float(1e3 * np.sqrt(np.mean(e.variance))) for e in experiments},
        residual_autocorrelation(experiments, preds),
    )


def _ageing_report(
    prob: Problem, x: np.ndarray, J: np.ndarray, r: np.ndarray, opt: Options
) -> dict[str, dict[str, dict[str, object]]]:
    """Each file's ageing values, 95 % intervals (eq. 46 from the covariance of all parameters, the pseudo-inverse if
    singular; ``ci95_scaled`` with s²) and bound flags: {file: {name: {...}}}."""
    from scipy import stats as _st

    assert prob.ageing is not None
    n, q = J.shape
    dof = n - q
    s2 = float(r @ r / dof) if dof > 0 else float("nan")
    tval = float(_st.t.ppf(0.975, dof)) if dof > 0 else float("nan")
    sig = np.sqrt(np.diag(statistics.pseudo_covariance(J, opt.rcond)[0]))
    out: dict[str, dict[str, dict[str, object]]] = {}
    k = len(prob.ageing.names)
    for g, label in enumerate(prob.files):
        out[label] = {}
        for j, name in enumerate(prob.ageing.names):
            pos = len(prob.names) + prob.n_nuis + g * k + j
            lo, hi = prob.ageing.bounds(name)
            value = prob.ageing.denormalise(name, float(x[pos]))
            half = tval * float(sig[pos]) * (hi - lo)

            def ci(h: float, value: float = value, lo: float = lo, hi: float = hi) -> list[float] | None:
                return [max(lo, value - h), min(hi, value + h)] if np.isfinite(h) else None

            xb = float(x[pos])
            out[label][name] = {
                "value": value,
                "ci95": ci(half),
                "ci95_scaled": ci(half * np.sqrt(s2)),
                "bounds": [lo, hi],
                "at_bound": "lower" if xb < opt.bound_tol else "upper" if xb > 1 - opt.bound_tol else None,
            }
    return out


@dataclass(frozen=True)
class Stage:
    """One stage of a group-wise design: the group's parameters and the experiments designed for it."""

    names: tuple[str, ...]
    experiments: tuple[Experiment, ...]


class StageError(Exception):
    """A stage of a group-wise fit failed: which one (1-based, of ``total``), the results of the stages before it
    (finished, in order) and the exception that ended it (also ``__cause__``)."""

    def __init__(self, stage: int, total: int, names: Sequence[str], done: Sequence[FitResult], cause: Exception):
        self.stage, self.total, self.names = stage, total, tuple(names)
        self.done, self.cause = list(done), cause
        what = " ".join(str(cause).split())  # one line, whatever the cause's text
        what = what if isinstance(cause, InputError) else f"{type(cause).__name__}: {what}"
        super().__init__(f"stage {stage} of {total} ({len(self.names)} parameters) failed: {what}")
