"""Equilibrium identification from a slow (C/20–C/50) charge/discharge test (paper eqs. 10–21, Table 5).

Pseudo-OCV curve. The test is cut into its constant-current branches (|I| above 20 % of its maximum); the
charge passed is q(t) = −∫I dt [Ah] from the start (discharged charge counts positive). Where a discharge and
a charge branch cover the same q, the pseudo-OCV is their mean: the C/20 overpotential and the hysteresis are
about symmetric, so the mean cancels them to first order (``half_gap_mV`` reports half the difference). Where
only one branch exists, that branch is shifted towards equilibrium by its own overpotential, measured as the
voltage jump at the step from the preceding rest into the branch (the first sample after the current switches;
without a preceding rest no shift: the jump at the branch's end is not used, since at the end of a discharge it
is mostly the knee's diffusion relaxation). Rests are not used.

Fit (eqs. 13–19). With θ⁻(q) = θ⁻(0) − 3600 q/(F H⁻) and θ⁺(q) = (n_Li − H⁻θ⁻(q))/H⁺ (eqs. 10, 13), the
model is V(q) = U⁺(θ⁺(q)) − U⁻(θ⁻(q)) (eqs. 14–15). The unknowns x = [θ⁻(0), H⁺, H⁻, n_Li] of eq. 16 are
solved for in an equivalent box-bounded form: the four stoichiometries at the ends of the data, θ⁻(q₀),
θ⁻(q₁), θ⁺(q₀), θ⁺(q₁) ∈ [0, 1], so every evaluation stays inside the OCP functions' domain; H± and n_Li follow
exactly. Bounded nonlinear least squares (scipy ``least_squares``, trust-region reflective) from a grid of
start points (the problem is not convex). Eq. 18 (V = V_max at k = 0) is not imposed: the data need not start
at V_max; instead the stoichiometry window is where the fitted OCV reaches V_max and V_min (eq. 20, with its
min/max labels fixed for the negative electrode), the electrode capacities Q± = F H±/3600 and the cell
capacity Q = |Δθ⁻| F H⁻ /3600 [Ah] (eqs. 12, 21 in Ah).

Beyond the paper (``ocp_terms``): the built-in cell's positive OCP is a Ni-rich stand-in for NCA. An optional
correction ΔU⁺(θ⁺) = Σ c_j exp(−((θ⁺ − μ_j)/w)²), Gaussian bumps at evenly spaced centres μ_j over the θ⁺
range of the data (width w = their spacing; it fades outside, where the stand-in's steep ends are kept), is
fitted with the window, and the corrected U⁺ is written into the identified cell as an expression (exp only,
so PyBaMM reads its BPX). With zero terms (the default) this is exactly the paper's method. The correction
also absorbs part of the window (it trades with the graphite features), so the windows are less well
determined with it than the RMSE suggests.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, least_squares

from battlab.cell import Cell, F
from battlab.functions import Expr
from protocols.errors import InputError


@dataclass(frozen=True)
class OcvCurve:
    """Pseudo-OCV [V] versus discharged charge q [Ah] from the start of the test, on a uniform q grid."""

    q: np.ndarray
    voltage: np.ndarray
    method: str  # how charge and discharge were combined
    half_gap_mV: float  # mean half difference charge − discharge where both exist
    source: str = ""


def _branches(t: np.ndarray, current: np.ndarray, threshold: float) -> list[tuple[int, int, int]]:
    """(start, stop, sign) of runs with |I| > threshold and constant sign (stop exclusive)."""
    sgn = np.where(current > threshold, 1, np.where(current < -threshold, -1, 0))
    runs = []
    k = 0
    n = sgn.size
    while k < n:
        j = k
        while j + 1 < n and sgn[j + 1] == sgn[k]:
            j += 1
        if sgn[k] != 0 and j - k >= 4:
            runs.append((k, j + 1, int(sgn[k])))
        k = j + 1
    return runs


def ocv_curve(
    t: np.ndarray,
    current: np.ndarray,
    voltage: np.ndarray,
    *,
    n_grid: int = 600,
    source: str = "",
    branch: str = "both",
) -> OcvCurve:
    """The pseudo-OCV from a slow test (current positive = charge, A; t in s); see the module docstring.

    ``branch`` "discharge" (or "charge") uses that branch alone, shifted by its rest-step overpotential: the
    equilibrium of a cell with hysteresis on the side its discharge (charge) tests see, instead of the mean."""
    if branch not in ("both", "discharge", "charge"):
        raise InputError(f"OCV branch {branch!r}: expected both, discharge or charge")
    t, current, voltage = (np.asarray(a, float) for a in (t, current, voltage))
    if t.size < 10:
        raise InputError(f"{source or 'OCV data'}: too few samples ({t.size}) for an OCV curve")
    q = np.concatenate([[0.0], np.cumsum(-current[:-1] * np.diff(t))]) / 3600.0
    imax = float(np.max(np.abs(current)))
    runs = _branches(t, current, 0.2 * imax)
    dis = [r for r in runs if r[2] < 0 and branch != "charge"]
    chg = [r for r in runs if r[2] > 0 and branch != "discharge"]
    if not dis and not chg:
        what = "" if branch == "both" else f"{branch} "
        raise InputError(f"{source or 'OCV data'}: no constant-current {what}branch found")

    def longest(rs: list[tuple[int, int, int]]) -> tuple[int, int, int] | None:
        return max(rs, key=lambda r: r[1] - r[0]) if rs else None

    def jump(r: tuple[int, int, int]) -> tuple[float, float]:
        """Overpotential magnitude at the branch's start and end (0 when no rest adjoins)."""
        a, b, _ = r
        j0 = abs(voltage[a] - voltage[a - 1]) if a > 0 and abs(current[a - 1]) < 0.05 * imax else np.nan
        j1 = abs(voltage[b] - voltage[b - 1]) if b < voltage.size and abs(current[b]) < 0.05 * imax else np.nan
        return float(j0), float(j1)

    d, c = longest(dis), longest(chg)
    lo = min(q[r[0] : r[1]].min() for r in (d, c) if r is not None)
    hi = max(q[r[0] : r[1]].max() for r in (d, c) if r is not None)
    grid = np.linspace(lo, hi, n_grid)

    def on_grid(r: tuple[int, int, int]) -> np.ndarray:
        qq, vv = q[r[0] : r[1]], voltage[r[0] : r[1]]
        o = np.argsort(qq)
        return np.interp(grid, qq[o], vv[o], left=np.nan, right=np.nan)

    vd = on_grid(d) if d else np.full(n_grid, np.nan)
    vc = on_grid(c) if c else np.full(n_grid, np.nan)
    both = np.isfinite(vd) & np.isfinite(vc)
    out = np.where(both, 0.5 * (vd + vc), np.nan)
    half_gap = float(1e3 * np.mean(0.5 * (vc - vd)[both])) if both.any() else float("nan")
    notes = []
    for branch, v, sign in ((d, vd, -1), (c, vc, +1)):
        if branch is None:
            continue
        only = np.isfinite(v) & ~both
        if only.sum() < 2:
            out = np.where(only, np.nan, out)
            continue
        j0, j1 = jump(branch)
        shift = j0 if np.isfinite(j0) else 0.0
        out = np.where(only, v - sign * shift, out)
        notes.append(
            f"{'discharge' if sign < 0 else 'charge'} only on {only.mean():.0%} of the range, shifted by "
            f"its rest-step overpotential ({1e3 * shift:.1f} mV)"
        )
    keep = np.isfinite(out)
    method = "mean of charge and discharge at equal charge passed" if both.any() else "single branch"
    if notes:
        method += "; " + "; ".join(notes)
    return OcvCurve(grid[keep], out[keep], method, half_gap, source)


@dataclass(frozen=True)
class Equilibrium:
    """Identified equilibrium parameters (Table 4), windows (eq. 20), capacities (eq. 21, Ah), fit quality."""

    theta_n0: float  # θ⁻ at q = 0 (the data's first point)
    H_n: float  # mol (eq. 11)
    H_p: float
    n_Li: float  # mol (eq. 10)
    eps_s_n: float
    eps_s_p: float
    Q_n: float  # Ah (eq. 12 / 3600)
    Q_p: float
    Q_Li: float  # F n_Li / 3600 [Ah]
    capacity: float  # Ah between V_min and V_max (eq. 21)
    window: tuple[float, float, float, float]  # θ⁻ at 0 %, θ⁻ at 100 %, θ⁺ at 0 %, θ⁺ at 100 %
    table5: dict[float, float]  # SOC → OCV [V]
    rmse_mV: float  # over the whole curve
    rmse_5_95_mV: float  # over 5–95 % SOC
    max_error_5_95_mV: float
    area_scale: float  # electrode area relative to the base cell (1: unchanged)
    ocp_correction: tuple[float, ...]  # bump amplitudes on the θ⁺ range [V]
    correction_window: tuple[float, float]
    curve: OcvCurve
    model_voltage: np.ndarray  # fitted OCV at curve.q
    soc: np.ndarray  # SOC of each curve point
    cell: Cell  # the identified cell
    converged: bool
    message: str

    def report(self) -> dict[str, object]:
        """JSON-able summary (Table 4, windows, capacities, Table 5, RMSEs, how the curve was made)."""
        return {
            "eps_s_n": self.eps_s_n,
            "eps_s_p": self.eps_s_p,
            "n_Li": self.n_Li,
            "H_n_mol": self.H_n,
            "H_p_mol": self.H_p,
            "Q_n_Ah": self.Q_n,
            "Q_p_Ah": self.Q_p,
            "Q_Li_Ah": self.Q_Li,
            "capacity_Ah": self.capacity,
            "window": {
                "sto_n_0": self.window[0],
                "sto_n_100": self.window[1],
                "sto_p_0": self.window[2],
                "sto_p_100": self.window[3],
            },
            "table5": {f"{int(round(100 * s))}%": v for s, v in self.table5.items()},
            "rmse_mV": self.rmse_mV,
            "rmse_5_95_mV": self.rmse_5_95_mV,
            "max_error_5_95_mV": self.max_error_5_95_mV,
            "area_scale": self.area_scale,
            "ocp_correction_terms": len(self.ocp_correction),
            "curve_method": self.curve.method,
            "half_gap_mV": self.curve.half_gap_mV,
            "converged": self.converged,
            "message": self.message,
        }


def _centres(a: float, b: float, n: int) -> tuple[np.ndarray, float]:
    lo, hi = min(a, b), max(a, b)
    centres = np.linspace(lo, hi, n)
    width = (hi - lo) / max(n - 1, 1)
    return centres, width


def _bumps(x: np.ndarray, coeffs: np.ndarray, a: float, b: float) -> np.ndarray:
    """ΔU⁺(x) = Σ c_j exp(−((x − μ_j)/w)²): Gaussian bumps at even centres μ_j over [a, b], width = spacing."""
    centres, width = _centres(a, b, len(coeffs))
    return np.sum([c * np.exp(-(((x - m) / width) ** 2)) for c, m in zip(coeffs, centres, strict=True)], axis=0)


def correction_expr(coeffs: tuple[float, ...], window: tuple[float, float]) -> str:
    """ΔU⁺ as an expression in x (exp only, so PyBaMM's BPX reader takes it)."""
    centres, width = _centres(window[0], window[1], len(coeffs))
    terms = [
        f"{float(c)!r}*exp(-((x - {float(m)!r})/{float(width)!r})**2)" for c, m in zip(coeffs, centres, strict=True)
    ]
    return " + ".join(terms) if terms else "0"


def fit_equilibrium(
    curve: OcvCurve,
    cell: Cell,
    *,
    ocp_terms: int = 0,
    rated_capacity: float | None = None,
    max_packing: float = 0.03,
) -> Equilibrium:
    """Fit eqs. 16–19 to a pseudo-OCV curve with ``cell``'s OCPs, geometry and voltage limits.

    Returns the identified parameters and ``cell`` updated with ε_s±, n_Li (and U⁺ corrected when
    ``ocp_terms`` > 0; ``Q_nom`` set to ``rated_capacity`` when given). When an electrode holds more active
    material than its geometry allows (ε_s + ε_e > 1 − ``max_packing``), the electrode area A is scaled up (a
    longer jelly roll, as in a higher-capacity cell of the same format) and ε_s± scaled down by the same factor;
    H± and n_Li are unchanged, and ``area_scale`` reports it.
    """
    q, y = curve.q, curve.voltage
    if q.size < 8:
        raise InputError(f"{curve.source or 'OCV curve'}: too few points ({q.size}) to fit")
    q0, q1 = float(q[0]), float(q[-1])
    s = (q - q0) / (q1 - q0)
    nc = int(ocp_terms)

    def parts(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a, b, c, d = p[:4]
        tn, tp = a + (b - a) * s, c + (d - c) * s
        corr = _bumps(tp, p[4:], c, d) if nc else 0.0
        return tn, tp, corr

    def model(p: np.ndarray) -> np.ndarray:
        tn, tp, corr = parts(p)
        return cell.fn("U_p", tp) + corr - cell.fn("U_n", tn)

    lb = np.r_[np.zeros(4), np.full(nc, -0.5)]
    ub = np.r_[np.ones(4), np.full(nc, 0.5)]
    best = None
    for a, b, c, d in itertools.product((0.7, 0.8, 0.9), (0.01, 0.05), (0.15, 0.3), (0.8, 0.95)):
        x0 = np.r_[a, b, c, d, np.zeros(nc)]
        sol = least_squares(
            lambda p: model(p) - y,
            x0,
            bounds=(lb, ub),
            method="trf",
            x_scale=np.r_[np.full(4, 0.05), np.full(nc, 0.01)],
        )
        if best is None or sol.cost < best.cost:
            best = sol
    p = best.x
    a, b, c, d = p[:4]
    if not (a > b and d > c):
        raise InputError(
            f"{curve.source or 'OCV curve'}: fit gives θ⁻ {a:.3f}→{b:.3f}, θ⁺ {c:.3f}→{d:.3f}; expected θ⁻ to fall "
            "and θ⁺ to rise with discharge: is the data a discharge-direction OCV of this chemistry?"
        )
    dq_C = (q1 - q0) * 3600.0
    H_n = dq_C / (F * (a - b))
    H_p = dq_C / (F * (d - c))
    theta_n_at_q0 = a
    n_li = H_n * a + H_p * c
    theta_n0 = theta_n_at_q0 + q0 * 3600.0 / (F * H_n)  # at q = 0
    coeffs = tuple(float(v) for v in p[4:])
    corr_window = (float(c), float(d))
    area = float(cell["A"])
    eps = {e: H / (float(cell[f"L_{e}"]) * area * float(cell[f"c_max_{e}"])) for e, H in (("n", H_n), ("p", H_p))}

    over = max(eps["n"] + float(cell["eps_e_n"]), eps["p"] + float(cell["eps_e_p"])) - (1.0 - max_packing)
    values: dict[str, object] = {}
    if over > 0:  # more active material than the geometry holds: a longer jelly roll (larger area A)
        scale = max((eps[e] / (1.0 - max_packing - float(cell[f"eps_e_{e}"]))) for e in "np")
        area *= scale
        eps = {e: v / scale for e, v in eps.items()}
        values["A"] = area

    values.update({"eps_s_n": eps["n"], "eps_s_p": eps["p"], "n_Li": n_li})
    if nc:
        base = cell["U_p"]
        text = base.text if isinstance(base, Expr) else None
        if text is None:
            raise InputError(f"cell {cell.name!r}: its U_p is a table; an OCP correction needs an expression")
        values["U_p"] = f"({text}) + ({correction_expr(coeffs, corr_window)})"
    if rated_capacity is not None:
        values["Q_nom"] = float(rated_capacity)
    drop = {k for k in ("sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100") if k in cell.values}
    base_vals = {k: v for k, v in cell.values.items() if k not in drop}
    try:
        new = Cell(
            cell.name,
            {**base_vals, **values},
            {k: v for k, v in cell.sources.items() if k not in values},
            cell.description,
            cell.extensions,
        )
    except InputError as exc:
        raise InputError(f"equilibrium fit: the identified values do not make a valid cell: {exc}") from None
    new = new.renamed(f"{cell.name}-ocv", f"{cell.description} (equilibrium identified from {curve.source or 'data'})")
    src = f"identified from the OCV test {curve.source}".strip()
    new = Cell(new.name, new.values, {**new.sources, **{k: src for k in values}}, new.description, new.extensions)
    window = new.stoichiometry_window()
    capacity = new.capacity()
    model_v = model(p)
    tn = parts(p)[0]
    soc = (tn - window[0]) / (window[1] - window[0])
    err = model_v - y
    inner = (soc >= 0.05) & (soc <= 0.95)
    table5 = {lvl: float(new.ocv(lvl)) for lvl in (0.8, 0.6, 0.4, 0.2)}
    return Equilibrium(
        theta_n0=float(theta_n0),
        H_n=float(H_n),
        H_p=float(H_p),
        n_Li=float(n_li),
        eps_s_n=float(values["eps_s_n"]),
        eps_s_p=float(values["eps_s_p"]),
        Q_n=float(F * H_n / 3600.0),
        Q_p=float(F * H_p / 3600.0),
        Q_Li=float(F * n_li / 3600.0),
        capacity=float(capacity),
        window=window,
        table5=table5,
        rmse_mV=float(1e3 * np.sqrt(np.mean(err**2))),
        rmse_5_95_mV=float(1e3 * np.sqrt(np.mean(err[inner] ** 2))) if inner.any() else float("nan"),
        max_error_5_95_mV=float(1e3 * np.max(np.abs(err[inner]))) if inner.any() else float("nan"),
        area_scale=float(area / float(cell["A"])),
        ocp_correction=coeffs,
        correction_window=corr_window,
        curve=curve,
        model_voltage=model_v,
        soc=soc,
        cell=new,
        converged=bool(best.status > 0),
        message=str(best.message),
    )


def soc_of_voltage(eq: Equilibrium, voltage: float) -> float:
    """SOC at a rest voltage on the identified OCV (clipped to [0, 1])."""
    cell = eq.cell
    lo, hi = float(cell.ocv(0.0)), float(cell.ocv(1.0))
    if voltage <= lo:
        return 0.0
    if voltage >= hi:
        return 1.0
    return float(brentq(lambda x: float(cell.ocv(x)) - voltage, 0.0, 1.0))
