"""Equilibrium identification with the full model: the slow (C/20) cycle simulated by the DFN, overpotentials
included, instead of the mean of its branches taken as the OCV (:mod:`battlab.identify.equilibrium`).

Why. The mean of the C/20 charge and discharge branches cancels the overpotential only where it is symmetric. Near
empty and full the solid diffusion shapes the branches (on ``nca18650-true``, τ⁻ = R_s²/D_s ≈ 4.3 h: the C/20
overpotential runs from 10 mV mid-range to 570 mV at 2.5 V), and the pseudo-OCV fit puts ε_s⁻ 2.9 % low.

Unknowns. The equilibrium parameters are fitted as the electrode moles H± = ε_s L A c_max and the cyclable lithium
n_Li (eqs. 10, 11), with the start stoichiometry θ⁻₀ at the rest before the cycle (the rest after a CCCV is still
relaxing); the cell follows from them by :func:`cell_with_moles`, which keeps ε_s + ε_e below 1 for every ε_e the
dynamic fit may reach (a longer jelly roll, i.e. a larger area A, where the moles need more room): a fit stays in
the physical region by its parameterisation. A few dynamic parameters that shape the C/20 curve (by default the
solid diffusivities, i.e. τ± at the start cell's radii) are fitted beside them as nuisances, with the model's exact
sensitivities; they are reported, not written into the cell.

Method (a fixed point on the simulated overpotential). The model voltage is V = U⁺(θ⁺) − U⁻(θ⁻) + η with θ± the
coulomb-counted mean stoichiometries (eqs. 13–15) and η the overpotential the DFN simulates for the logged current.
The model gives no sensitivities w.r.t. ε_s± (they are inputs of the compiled model, not parameters of θ̄: every
trial cell runs on one library), so η is held at the last simulated point while the moles move (their Jacobian
is the OCV's, exact), the nuisances move with their exact sensitivities, and the DFN is simulated again at the
result. At the fixed point the residual is the DFN's own; it converges because η depends weakly on the moles, and
linearly (a one-cycle C/20 test of the virtual cell: 18 simulations to 0.1 σ). Samples where the voltage is steep (the
ends, |dV/dSOC| > ``slope_max``) or where a branch has just started are left out: there η depends most on what is
not fitted, and a held η misplaces the knee when the moles move.

A current sensor's offset (``current_sensor.offset`` asked for among the nuisances) is an OCV unknown beside the
moles: the cell carries (I_log − offset)/(1 + gain), so the offset moves the charge count the stoichiometries are
counted on (15 mA is 11 % of a C/20 current of an 18650), which no nuisance held in η can follow. Its start is far
from the fixed point (the offset's charge shifts every stoichiometry), so there the nuisances wait while an unknown
still steps by more than ``HOLD_SIGMA`` σ, and a step that ends the cycle early at its cut-off is halved (tried for
every equilibrium fit: on a truth with a 12 mV graphite hysteresis, whose branches no equilibrium without it fits,
the halving ran out of simulations with the capacity 1.4 % low, and the quick campaign's fits failed from there).

Intervals: 95 % (eq. 46) from the Jacobian [OCV columns | sensitivities] of the last iteration, marginal over the
nuisances, with the residual's own variance and autocorrelation (:func:`hac_covariance`): no independent noise
estimate exists at this stage, and what the model still misses is correlated in time.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from battlab import parameters
from battlab.cell import Cell, F
from battlab.identify.equilibrium import Equilibrium, fit_equilibrium, ocv_curve
from protocols.errors import InputError
from protocols.profile import Profile

#: the dynamic parameters fitted beside the equilibrium by default (they shape the C/20 curve most)
NUISANCES: tuple[str, ...] = ("D_s_n", "D_s_p")
#: ε_s + (the upper bound of ε_e) may reach at most 1 − this
PACKING_MARGIN = 0.002
#: [V per unit SOC] samples steeper than this are not fitted (the ends of the window)
SLOPE_MAX = 4.0
#: [s] samples this soon after a branch starts are not fitted
SETTLE_S = 600.0
#: simulations of the cycle at most: the fixed point closes linearly, each step about 0.6 of the last near the end
#: (on the virtual cell's C/20 cycle 18 simulations to 0.1 σ, each a few seconds: the trial cells share the model)
MAX_SIMULATIONS = 24
#: the largest step of a nuisance per simulation, in θ̄
NUISANCE_STEP = 0.3
#: with a sensor's offset fitted: while an OCV unknown still steps by more than this many σ, the nuisances are held
#: (far from the fixed point the held η is far from the DFN's, and the nuisances' linear step with it can take the
#: cycle past its cut-off)
HOLD_SIGMA = 30.0
#: with a sensor's offset fitted: a step after which fewer than this fraction of the fitted samples are simulated
#: (the cycle ended at its cut-off) is halved
SHORT_FRACTION = 0.9
#: a current sensor's offset, when asked for among the nuisances, is an OCV unknown (it moves the charge count);
#: its step scale [A]
SENSOR = "current_sensor"
OFFSET = f"{SENSOR}.offset"
OFFSET_SCALE_A = 1e-4


@dataclass(frozen=True)
class SlowCycle:
    """The logged slow cycle from the last sample of the rest before it: t [s] from 0, current [A, + = charge],
    voltage [V]; the first sample is at rest."""

    t: np.ndarray
    current: np.ndarray
    voltage: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        if self.t.size < 20 or not (np.diff(self.t) > 0).all():
            raise InputError(f"{self.source or 'slow cycle'}: expected at least 20 samples at increasing times")


def slow_cycle(t: np.ndarray, current: np.ndarray, voltage: np.ndarray, first: int, source: str = "") -> SlowCycle:
    """The cycle starting at row ``first`` of a log, preceded by its rest's last row (``first`` − 1, kept at zero
    current: it only gives the start voltage)."""
    if first < 1 or abs(float(current[first - 1])) > 0.05 * float(np.max(np.abs(current))):
        raise InputError(f"{source or 'slow cycle'}: the cycle must follow a rest (row {first - 1} carries current)")
    i = np.asarray(current[first - 1 :], float).copy()
    i[0] = 0.0
    t = np.asarray(t[first - 1 :], float)
    return SlowCycle(t - t[0], i, np.asarray(voltage[first - 1 :], float), source)


def electrode_volume(cell: Cell, e: str) -> float:
    """L A c_max [mol per unit ε_s] of electrode ``e`` ("n" or "p")."""
    return float(cell[f"L_{e}"]) * float(cell["A"]) * float(cell[f"c_max_{e}"])


def cell_with_moles(cell: Cell, H_n: float, H_p: float, n_li: float, margin: float = PACKING_MARGIN) -> Cell:
    """``cell`` with electrode moles H± [mol] and lithium n_Li [mol]: ε_s = H/(L A c_max), the area A scaled up
    where ε_s + (ε_e's upper bound) would exceed 1 − ``margin`` (H± unchanged), so that no ε_e a fit may reach
    makes the electrode impossible."""
    if min(H_n, H_p, n_li) <= 0:
        raise InputError(f"electrode moles and lithium must be positive, got H⁻ {H_n:g}, H⁺ {H_p:g}, n_Li {n_li:g}")
    room = {e: 1.0 - margin - parameters.SPECS[f"eps_e_{e}"].upper for e in "np"}
    eps = {"n": H_n / electrode_volume(cell, "n"), "p": H_p / electrode_volume(cell, "p")}
    scale = max(1.0, *(eps[e] / room[e] for e in "np"))
    values: dict[str, float] = {"eps_s_n": eps["n"] / scale, "eps_s_p": eps["p"] / scale, "n_Li": n_li}
    if scale > 1.0:
        values["A"] = float(cell["A"]) * scale
    drop = {"sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100"}
    return Cell(
        cell.name,
        {**{k: v for k, v in cell.values.items() if k not in drop}, **values},
        cell.sources,
        cell.description,
        cell.extensions,
    )


@dataclass(frozen=True)
class Iteration:
    """One simulation of the cycle: DFN RMSE on the fitted samples [mV], and the step it led to in units of σ."""

    rmse_mV: float
    step_sigma: float
    seconds: float


@dataclass(frozen=True)
class ModelEquilibrium:
    """The equilibrium fitted with the full model (see the module docstring)."""

    cell: Cell
    H_n: float
    H_p: float
    n_Li: float
    theta_n0: float  # θ⁻ at the rest before the cycle
    estimates: dict[str, float]  # eps_s_n, eps_s_p, n_Li, H_n, H_p, capacity_Ah
    ci95: dict[str, tuple[float, float]]
    nuisances: dict[str, float]  # fitted dynamic values (physical units)
    s2: float  # residual variance of the fitted samples [V²]
    rmse_mV: float  # DFN against data on the fitted samples at the result
    rmse_all_mV: float  # on every sample of the cycle
    n_fitted: int
    n_samples: int
    iterations: tuple[Iteration, ...]
    converged: bool
    message: str
    start: Equilibrium  # the pseudo-OCV fit it started from
    seconds: float
    model_voltage: np.ndarray = field(repr=False)

    @property
    def untrusted_because(self) -> list[str]:
        """Why its intervals cannot be trusted (empty: they can): a fit that stopped before its fixed point has
        intervals around a point that is not the estimate."""
        return [] if self.converged else [f"the equilibrium fit did not converge ({self.message})"]

    def report(self) -> dict[str, object]:
        """JSON-able summary: the estimates with intervals (and whether they can be trusted), the nuisances, fit
        quality and convergence."""
        c = self.cell
        n0, n1, p0, p1 = c.stoichiometry_window()
        return {
            "method": "full model (DFN) of the slow cycle, overpotential simulated",
            **self.estimates,
            "ci95": {k: list(v) for k, v in self.ci95.items()},
            "area_scale": float(c["A"]) / float(self.start.cell["A"]) * self.start.area_scale,
            "window": {"sto_n_0": n0, "sto_n_100": n1, "sto_p_0": p0, "sto_p_100": p1},
            "nuisances": self.nuisances,
            "rmse_mV": self.rmse_mV,
            "rmse_all_mV": self.rmse_all_mV,
            "s2_V2": self.s2,
            "fitted_samples": self.n_fitted,
            "samples": self.n_samples,
            "iterations": [
                {"rmse_mV": i.rmse_mV, "step_sigma": i.step_sigma, "seconds": i.seconds} for i in self.iterations
            ],
            "converged": self.converged,
            "message": self.message,
            "trusted": not self.untrusted_because,
            "untrusted_because": self.untrusted_because,
            "seconds": self.seconds,
            "pseudo_ocv": {
                "eps_s_n": self.start.eps_s_n,
                "eps_s_p": self.start.eps_s_p,
                "n_Li": self.start.n_Li,
                "capacity_Ah": self.start.capacity,
                "half_gap_mV": self.start.curve.half_gap_mV,
            },
        }


def fitted_samples(
    cycle: SlowCycle, capacity_ah: float, slope_max: float = SLOPE_MAX, settle_s: float = SETTLE_S
) -> np.ndarray:
    """The samples the fit uses: in a constant-current branch (|I| > half the largest), ``settle_s`` after its start,
    where the data's |dV/dSOC| (over 5 samples, SOC on ``capacity_ah``) is below ``slope_max``."""
    t, i, v = cycle.t, cycle.current, cycle.voltage
    imax = float(np.max(np.abs(i)))
    cc = np.abs(i) > 0.5 * imax
    start = np.zeros(t.size)
    for k in range(1, t.size):
        same = cc[k] and cc[k - 1] and np.sign(i[k]) == np.sign(i[k - 1])
        start[k] = start[k - 1] if same else t[k]
    soc = np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t))]) / 3600.0 / capacity_ah
    dv, ds = v[4:] - v[:-4], soc[4:] - soc[:-4]
    slope = np.full(t.size, np.inf)
    ok = np.abs(ds) > 0
    slope[2:-2][ok] = np.abs(dv[ok] / ds[ok])
    return cc & (t - start >= settle_s) & (slope < slope_max)


def fit_equilibrium_model(
    cycle: SlowCycle,
    cell: Cell,
    *,
    nuisances: Sequence[str] = NUISANCES,
    start: Equilibrium | None = None,
    max_simulations: int = MAX_SIMULATIONS,
    tol_sigma: float = 0.1,
    mask: np.ndarray | None = None,
    progress: object | None = None,
) -> ModelEquilibrium:
    """Fit H±, n_Li and θ⁻₀ (and the ``nuisances``) to ``cycle`` with ``cell``'s OCPs, geometry and other dynamic
    values (see the module docstring). ``start``: the pseudo-OCV fit to start from (default: made here). Stops when
    a step moves no unknown by more than ``tol_sigma`` of its σ, or after ``max_simulations``. ``current_sensor.offset``
    among the nuisances (the cell carrying the extension) is fitted with the moles: the cell carries
    (I_log − offset)/(1 + gain), so the offset moves the charge count itself (15 mA at C/20 is 11 % of it); the gain
    stays at the cell's value (it scales every mole alike: the slow cycle cannot tell it from the capacity)."""
    from battlab.identify.forward import ForwardModel

    w0 = time.perf_counter()
    nuis = parameters.check_names(list(nuisances))
    where = cycle.source or "slow cycle"
    if start is None:
        start = fit_equilibrium(ocv_curve(cycle.t, cycle.current, cycle.voltage, source=cycle.source), cell)
    use = fitted_samples(cycle, start.capacity) if mask is None else np.asarray(mask, bool)
    if use.sum() < 50:
        raise InputError(f"{where}: only {int(use.sum())} samples away from the ends and the branches' starts")
    q = np.concatenate([[0.0], np.cumsum(cycle.current[:-1] * np.diff(cycle.t))])  # C, + = charge (logged)
    V = cycle.voltage
    prof = Profile(cycle.t, cycle.current)
    # a cell with a current sensor carries I = (I_log − offset)/(1 + gain): its charge count moves with the offset
    # (an OCV unknown like θ⁻₀; the gain scales every mole alike, so the slow cycle does not inform it)
    sensor = OFFSET in nuis
    nuis = tuple(n for n in nuis if n != OFFSET)
    gain = cell.value(f"{SENSOR}.gain") if sensor else 0.0
    nx = 5 if sensor else 4

    def ocv(x: np.ndarray) -> np.ndarray:
        hn, hp, nli, tn0 = x[:4]
        qc = (q - x[4] * cycle.t) / (1.0 + gain) if sensor else q
        tn = tn0 + qc / (F * hn)
        tp = (nli - hn * tn) / hp
        return cell.fn("U_p", np.clip(tp, 1e-9, 1 - 1e-9)) - cell.fn("U_n", np.clip(tn, 1e-9, 1 - 1e-9))

    x = np.array([start.H_n, start.H_p, start.n_Li, start.theta_n0])
    scale = np.abs(x) * 1e-3
    if sensor:
        x = np.r_[x, cell.value(OFFSET)]
        scale = np.r_[scale, OFFSET_SCALE_A]
    th = np.array([cell.normalised(n) for n in nuis])
    iters: list[Iteration] = []
    converged, message = False, f"not converged in {max_simulations} simulations"
    fm: ForwardModel | None = None
    J, rows = np.zeros((0, 0)), use
    last: tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray] | None = None  # the step before
    for _ in range(max_simulations):
        t0 = time.perf_counter()
        out = _simulate(fm, cell, x, th, nuis, prof, where)
        fm = out.model
        eta = out.voltage - ocv(x)
        ok = use & np.isfinite(eta)
        if sensor and last is not None and ok.sum() < SHORT_FRACTION * last[2]:
            # the step ended the cycle early (past its cut-off): back to where it began, half the step
            x0, th0, n0, dx, dth = last
            x, th = x0 + dx / 2, th0 + dth / 2
            fm = None if np.any(dx[:3]) else fm
            last = (x0, th0, n0, dx / 2, dth / 2)
            continue
        if ok.sum() < 50:
            raise InputError(f"{where}: the model of the cycle ends at its cut-off before the samples it would fit")
        rmse = float(1e3 * np.sqrt(np.mean((out.voltage - V)[ok] ** 2)))

        at = x.copy()

        def residual(
            z: np.ndarray, x: np.ndarray = at, eta: np.ndarray = eta, S: np.ndarray = out.S, ok: np.ndarray = ok
        ) -> np.ndarray:
            return (ocv(x + z[:nx] * scale) + eta + S @ z[nx:] - V)[ok]

        lo = np.r_[np.full(nx, -np.inf), -th]
        hi = np.r_[np.full(nx, np.inf), 1.0 - th]
        sol = least_squares(residual, np.zeros(nx + len(nuis)), bounds=(lo, hi), method="trf", x_scale="jac")
        J, rows = sol.jac, ok
        dof = max(int(ok.sum()) - J.shape[1], 1)
        cov = float(2 * sol.cost / dof) * np.linalg.pinv(J.T @ J)
        steps = np.abs(sol.x) / np.sqrt(np.maximum(np.diag(cov), 1e-300))
        iters.append(Iteration(rmse, float(steps.max()), time.perf_counter() - t0))
        if callable(progress):
            progress(len(iters), rmse, float(steps.max()))
        # the start stoichiometry and the nuisances move at every simulation (the same cell); the moles and the
        # lithium only when they move by a σ or more (a new cell)
        if steps.max() < tol_sigma:
            converged, message = True, f"converged: the last step moved no unknown by more than {steps.max():.2g} σ"
            break
        # the nuisances' linearisation holds for modest steps: the whole step shrinks to at most NUISANCE_STEP in θ̄
        z = sol.x * min(1.0, NUISANCE_STEP / max(float(np.max(np.abs(sol.x[nx:]), initial=0.0)), 1e-300))
        if sensor and steps[:nx].max() >= HOLD_SIGMA:  # far from the fixed point: the OCV unknowns move first
            z = np.r_[sol.x[:nx], np.zeros(len(nuis))]
        x0, th0 = x.copy(), th.copy()
        th = np.clip(th + z[nx:], 0.0, 1.0)
        x[3:] += z[3:nx] * scale[3:]
        if steps[:3].max() >= tol_sigma:  # a new cell only when the moles or the lithium move
            x[:3] += z[:3] * scale[:3]
            fm = None
        last = (x0, th0, int(ok.sum()), x - x0, th - th0)
    end = _simulate(fm, cell, x, th, nuis, prof, where, sensitivities=False)
    vd = end.voltage
    hn, hp, nli, tn0 = (float(v) for v in x[:4])
    new = cell_with_moles(cell, hn, hp, nli)
    if sensor:
        new = new.with_values(**{OFFSET: float(x[4])})
    ok = use & np.isfinite(vd)
    dof = max(int(ok.sum()) - J.shape[1], 1)
    s2 = float(np.sum((vd - V)[ok] ** 2) / dof)
    r = np.nan_to_num((vd - V)[rows])
    cov = hac_covariance(J, r, dof)
    tval = float(stats.t.ppf(0.975, dof))
    # intervals of the moles and lithium (physical units), and of ε_s (through the cell's rule) and the capacity
    sig = np.sqrt(np.maximum(np.diag(cov)[:3], 0.0)) * scale[:3]
    est = {"H_n": hn, "H_p": hp, "n_Li": nli}
    ci = {n: (v - tval * s, v + tval * s) for (n, v), s in zip(est.items(), sig, strict=True)}
    for e, h in (("n", "H_n"), ("p", "H_p")):
        per = electrode_volume(new, e)  # L A c_max of the identified cell
        est[f"eps_s_{e}"] = float(new[f"eps_s_{e}"])
        ci[f"eps_s_{e}"] = (ci[h][0] / per, ci[h][1] / per)
    est["capacity_Ah"] = float(new.capacity())
    ci["capacity_Ah"] = _capacity_interval(
        new, np.array([hn, hp, nli]), cov[:3, :3] * np.outer(scale[:3], scale[:3]), tval
    )
    for j, n in enumerate(nuis):  # an extension's parameter fitted as a nuisance: its interval too
        if n in parameters.EXTENSION_SPECS:
            sp, s_th = parameters.spec(n), float(np.sqrt(max(cov[nx + j, nx + j], 0.0)))
            lo, hi = (sp.denormalise(float(np.clip(th[j] + d * tval * s_th, 0.0, 1.0))) for d in (-1, 1))
            ci[n] = (lo, hi)
    if sensor:
        s_off = float(np.sqrt(max(cov[4, 4], 0.0))) * scale[4]
        est[OFFSET] = float(x[4])
        ci[OFFSET] = (float(x[4]) - tval * s_off, float(x[4]) + tval * s_off)
    return ModelEquilibrium(
        cell=new.renamed(f"{cell.name}-ocv", f"{cell.description} (equilibrium identified with the full model)"),
        H_n=hn,
        H_p=hp,
        n_Li=nli,
        theta_n0=tn0,
        estimates=est,
        ci95=ci,
        nuisances={n: parameters.spec(n).denormalise(float(v)) for n, v in zip(nuis, th, strict=True)},
        s2=s2,
        rmse_mV=float(1e3 * np.sqrt(np.mean((vd - V)[ok] ** 2))),
        rmse_all_mV=float(1e3 * np.sqrt(np.nanmean((vd - V) ** 2))),
        n_fitted=int(ok.sum()),
        n_samples=int(V.size),
        iterations=tuple(iters),
        converged=converged,
        message=message,
        start=start,
        seconds=time.perf_counter() - w0,
        model_voltage=vd,
    )


def _capacity_interval(cell: Cell, x: np.ndarray, cov: np.ndarray, tval: float) -> tuple[float, float]:
    """95 % interval of the capacity between V_min and V_max (eq. 21) by the delta method (difference columns)."""
    base = float(cell.capacity())
    grad = np.zeros(3)
    for j in range(3):
        h = 1e-6 * x[j]
        xp = x.copy()
        xp[j] += h
        grad[j] = (float(cell_with_moles(cell, *xp).capacity()) - base) / h
    s = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    return base - tval * s, base + tval * s


@dataclass(frozen=True)
class _Run:
    model: object  # the ForwardModel of the moles simulated (reused while they stay)
    voltage: np.ndarray  # [V] at every sample (NaN after an early end)
    S: np.ndarray  # dV/dθ̄ of the nuisances


def _simulate(
    fm: object | None,
    cell: Cell,
    x: np.ndarray,
    th: np.ndarray,
    nuis: Sequence[str],
    prof: Profile,
    where: str,
    sensitivities: bool = True,
) -> _Run:
    """The DFN on the cycle at moles, lithium and start stoichiometry ``x`` and nuisances ``th`` (θ̄); ``fm``: the
    model built for these moles (None: build it)."""
    from battlab.identify.forward import ForwardModel

    hn, hp, nli, tn0 = (float(v) for v in x[:4])
    tp0 = (nli - hn * tn0) / hp
    if not (0 < tn0 < 1 and 0 < tp0 < 1):
        raise InputError(f"{where}: the start stoichiometries left (0, 1) (θ⁻ {tn0:.4f}, θ⁺ {tp0:.4f})")
    model = fm if isinstance(fm, ForwardModel) else ForwardModel(cell_with_moles(cell, hn, hp, nli), v_margin=0.5)
    theta = model.cell.theta_bar()
    theta[[model.names.index(n) for n in nuis]] = th
    if x.size > 4:  # the current sensor's offset [A]
        theta[model.names.index(OFFSET)] = parameters.spec(OFFSET).normalise(float(x[4]))
    names = tuple(nuis) if sensitivities else ()
    out = model.run(theta, prof, 1.0, start=(tn0, tp0), sensitivities=names)
    n = prof.t.size
    v = np.full(n, np.nan)
    v[: out.voltage.size] = out.voltage
    S = np.zeros((n, len(nuis)))
    if names and out.sensitivities is not None:
        S[: out.voltage.size] = out.sensitivities
    return _Run(model, v, S)


def hac_covariance(J: np.ndarray, r: np.ndarray, dof: int, lags: int | None = None) -> np.ndarray:
    """Covariance of least-squares estimates robust to autocorrelated residuals (Newey–West): (JᵀJ)⁻¹ Ŝ (JᵀJ)⁻¹
    with Ŝ = Σ_l w_l Σ_t (g_t g_{t−l}ᵀ + g_{t−l} g_tᵀ)/2·(2 − δ_l0), g_t = J_t r_t, Bartlett weights w_l = 1 −
    l/(L + 1), L = ⌊4 (n/100)^(2/9)⌋ unless given; scaled by n/dof. With white residuals it is s² (JᵀJ)⁻¹."""
    n = r.size
    L = int(4 * (n / 100.0) ** (2.0 / 9.0)) if lags is None else int(lags)
    g = J * r[:, None]
    S = g.T @ g
    for lag in range(1, min(L, n - 1) + 1):
        G = g[lag:].T @ g[:-lag]
        S += (1.0 - lag / (L + 1.0)) * (G + G.T)
    A = np.linalg.pinv(J.T @ J)
    return (n / max(dof, 1)) * (A @ S @ A)


def against_truth(eq: ModelEquilibrium, truth: Cell) -> dict[str, dict[str, object]]:
    """Per equilibrium estimate (virtual lab): the truth, the relative bias, whether the 95 % interval covers the
    truth and whether it can be trusted (:attr:`ModelEquilibrium.untrusted_because`)."""
    true = {
        "eps_s_n": float(truth["eps_s_n"]) * float(truth["A"]) / float(eq.cell["A"]),  # the same moles at this area
        "eps_s_p": float(truth["eps_s_p"]) * float(truth["A"]) / float(eq.cell["A"]),
        "n_Li": truth.lithium_moles(),
        "H_n": truth.electrode_moles("n"),
        "H_p": truth.electrode_moles("p"),
        "capacity_Ah": float(truth.capacity()),
    }
    out: dict[str, dict[str, object]] = {}
    for name, t in true.items():
        lo, hi = eq.ci95[name]
        v = eq.estimates[name]
        out[name] = {
            "truth": t,
            "estimate": v,
            "bias": v / t - 1.0,
            "ci95": [lo, hi],
            "covered": bool(lo <= t <= hi),
            "trusted": not eq.untrusted_because,
        }
    return out
