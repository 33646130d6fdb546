"""Time integration with exact discrete forward sensitivities (staggered direct method).

Scheme: variable-step BDF2 on the DAE M ẏ = [f; g] (restarting with backward Euler, ω = 0, after a large current
step), every step solved by Newton to round-off. After each step the Newton matrix J = ∂R/∂y at the solution is
factorised once more and reused for all sensitivity right-hand sides:

    J S_{n+1} = −(∂R/∂x_n S_n + ∂R/∂x_{n−1} S_{n−1} + ∂R/∂θ̄),

which are the exact derivatives of the discrete solution (so they agree with finite differences of the same
scheme on the same grid). Outputs at a sample time t_k are the right limit: the algebraic states are re-solved
with the differential states at t_k and the current that starts there, with S_z = −g_z⁻¹(g_x S_x + g_θ̄).

Everything per step (Newton, factorisation, sensitivity solves) runs inside CasADi (a ``mapaccum`` over a chunk
of steps), so Python touches the loop only once per chunk.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.model.dfn import C_SCALE, DFN
from battlab.model.mesh import Mesh

NP = len(parameters.DYNAMIC)
NEWTON_FAIL = 1e-6  #: a step whose scaled residual stays above this has failed
_NEWTON = {"abstol": 1e-9, "abstolStep": 1e-14, "max_iter": 30, "error_on_fail": False, "linear_solver": "csparse"}


@dataclass(frozen=True)
class Settings:
    """Time-step control [s].

    Every change of the current larger than ``refine_rate`` × 1C (default: any change) restarts the scheme
    with a backward-Euler step of ``dt_first``, after which steps grow by ``growth`` up to ``dt_max``: BDF2
    carried across a kink of the solution is only first order (measured: 1.1 mV vs 0.04 mV on UDDS at 1 s
    samples). ``chunk``: steps per call of the CasADi stepper.
    """

    dt_max: float = 10.0
    dt_first: float = 0.25
    growth: float = 2.0
    refine_rate: float = 0.0
    chunk: int = 128


@dataclass
class Compiled:
    """The CasADi functions of one (cell, mesh, isothermal, number of sensitivities)."""

    model: DFN
    ns: int
    chunk: int
    step: ca.Function  # mapaccum over `chunk` steps
    out: ca.Function  # map over `chunk` samples
    out1: ca.Function  # one sample
    alg: ca.Function  # consistent algebraic state
    build_seconds: float = 0.0


def _residual_functions(model: DFN) -> tuple[ca.Function, ca.Function, ca.Function]:
    lay = model.layout
    nx, ny = lay.nx, lay.ny
    y = ca.SX.sym("y", ny)
    xn = ca.SX.sym("xn", nx)
    xp = ca.SX.sym("xp", nx)
    u = ca.SX.sym("u", 4)  # h [s], ω, I_dis [A], T_amb [K]
    th = ca.SX.sym("th", NP)
    h, w, I_dis, T_amb = u[0], u[1], u[2], u[3]
    eq = model.equations(y, I_dis, T_amb, th)
    gamma = (1 + w) / (1 + 2 * w)
    psi = (1 + w) ** 2 / (1 + 2 * w) * xn - w**2 / (1 + 2 * w) * xp
    R = ca.vertcat(y[:nx] - psi - gamma * h * eq["f"], eq["g"])
    res = ca.Function("res", [y, xn, xp, u, th], [R])
    # algebraic system and outputs at a given differential state
    z = ca.SX.sym("z", lay.nz)
    x = ca.SX.sym("x", nx)
    ua = ca.SX.sym("ua", 2)  # I_dis, T_amb
    eqa = model.equations(ca.vertcat(x, z), ua[0], ua[1], th)
    galg = ca.Function("galg", [z, x, ua, th], [eqa["g"]])
    sto = eqa["sto_surf"]
    outputs = ca.vertcat(eqa["V"], eqa["T1"], eqa["T2"], ca.mmin(sto), ca.mmax(sto))
    outf = ca.Function("outf", [z, x, ua, th], [outputs])
    return res, galg, outf


def compile_model(cell: Cell, mesh: Mesh, isothermal: bool, ns: int, chunk: int) -> Compiled:
    """Build (or fetch from the cache) the chunk functions; ``ns`` sensitivity directions (0: none)."""
    return _compile(cell, cell.static_hash(), mesh, isothermal, ns, chunk)


_CACHE: dict[tuple, Compiled] = {}


def _compile(cell: Cell, cell_hash: str, mesh: Mesh, isothermal: bool, ns: int, chunk: int) -> Compiled:
    key = (cell_hash, mesh, isothermal, ns, chunk)
    if key in _CACHE:
        return _CACHE[key]
    t0 = time.perf_counter()
    model = DFN(cell, mesh, isothermal=isothermal)
    lay = model.layout
    nx, nz, ny = lay.nx, lay.nz, lay.ny
    res, galg, outf = _residual_functions(model)

    # --- one step: Newton on R(y) = 0, then the sensitivity solves with the same matrix ---
    Y = ca.MX.sym("Y", ny)
    XN = ca.MX.sym("XN", nx)
    XP = ca.MX.sym("XP", nx)
    U = ca.MX.sym("U", 4)
    TH = ca.MX.sym("TH", NP)
    rf = ca.rootfinder("rf", "newton", res, _NEWTON)
    y_new = rf(Y, XN, XP, U, TH)
    # history: a zero-length step (padding) leaves states and history unchanged
    live = U[0] > 0
    xp_new = ca.if_else(live, XN, XP)
    ins = [Y, XP, U, TH]
    resid = ca.norm_inf(res(y_new, XN, XP, U, TH))  # Newton failure shows here (error_on_fail is off)
    outs = [y_new, xp_new]
    if ns:
        E = ca.MX.sym("E", NP, ns)  # selects the parameters to differentiate against
        SN = ca.MX.sym("SN", nx, ns)
        SP = ca.MX.sym("SP", nx, ns)
        ysym = ca.SX.sym("y", ny)
        xns = ca.SX.sym("xn", nx)
        xps = ca.SX.sym("xp", nx)
        us = ca.SX.sym("u", 4)
        ths = ca.SX.sym("th", NP)
        Rs = res(ysym, xns, xps, us, ths)
        jac = ca.Function(
            "stepjac",
            [ysym, xns, xps, us, ths],
            [ca.jacobian(Rs, ysym), ca.jacobian(Rs, xns), ca.jacobian(Rs, xps), ca.jacobian(Rs, ths)],
        )
        Jy, Jxn, Jxp, Jth = jac(y_new, XN, XP, U, TH)
        rhs = Jxn @ SN + Jxp @ SP + Jth @ E
        S_new = -ca.solve(Jy, rhs, "csparse")[:nx, :]
        sp_new = ca.if_else(live, SN, SP)
        ins = [Y, XP, SN, SP, U, TH, E]
        outs = [y_new, xp_new, S_new, sp_new, resid]
        # XN is the differential part of Y
        body = ca.Function("body", [Y, XP, SN, SP, U, TH, E], ca.substitute(outs, [XN], [Y[:nx]]))
        step = body.mapaccum("steps", chunk, [0, 1, 2, 3], [0, 1, 2, 3])
    else:
        body = ca.Function("body", ins, ca.substitute([*outs, resid], [XN], [Y[:nx]]))
        step = body.mapaccum("steps", chunk, [0, 1], [0, 1])

    # --- outputs at a sample (right limit): algebraic re-solve ---
    Z = ca.MX.sym("Z", nz)
    X = ca.MX.sym("X", nx)
    UA = ca.MX.sym("UA", 2)
    rfa = ca.rootfinder("rfa", "newton", galg, _NEWTON)
    z_sol = rfa(Z, X, UA, TH)
    o = outf(z_sol, X, UA, TH)
    alg = ca.Function("alg", [Z, X, UA, TH], [z_sol])
    if ns:
        zs, xs, uas, ths2 = ca.SX.sym("z", nz), ca.SX.sym("x", nx), ca.SX.sym("ua", 2), ca.SX.sym("th", NP)
        gs = galg(zs, xs, uas, ths2)
        os_ = outf(zs, xs, uas, ths2)
        ojac = ca.Function(
            "outjac",
            [zs, xs, uas, ths2],
            [
                ca.jacobian(gs, zs),
                ca.jacobian(gs, xs),
                ca.jacobian(gs, ths2),
                ca.jacobian(os_, zs),
                ca.jacobian(os_, xs),
                ca.jacobian(os_, ths2),
            ],
        )
        SX_ = ca.MX.sym("SX", nx, ns)
        E2 = ca.MX.sym("E", NP, ns)
        gz, gx, gth, oz, ox, oth = ojac(z_sol, X, UA, TH)
        Sz = -ca.solve(gz, gx @ SX_ + gth @ E2, "csparse")
        So = oz @ Sz + ox @ SX_ + oth @ E2  # (5, ns): V, T1, T2, sto_min, sto_max
        outfun = ca.Function("out1", [Z, X, UA, TH, SX_, E2], [z_sol, o, So[0, :], So[2, :]])
    else:
        outfun = ca.Function("out1", [Z, X, UA, TH], [z_sol, o])
    out = outfun.map(chunk)
    compiled = Compiled(model, ns, chunk, step, out, outfun, alg, time.perf_counter() - t0)
    _CACHE[key] = compiled
    return compiled


# ---------------------------------------------------------------------------------------------------------
# the step schedule


@dataclass(frozen=True)
class Schedule:
    """Steps (h [s], ω, I_dis [A]) and, per sample k ≥ 1, the index of the step that ends at t_k."""

    h: np.ndarray
    w: np.ndarray
    current: np.ndarray
    sample_step: np.ndarray


def next_step(remaining: float, h_allowed: float) -> float:
    """The next step [s] in what remains of a sample interval: all of it within 1.2 h_allowed, half of it within
    2 h_allowed, else h_allowed (so no sliver step ends an interval)."""
    if remaining <= 1.2 * h_allowed:
        return remaining
    if remaining <= 2.0 * h_allowed:
        return remaining / 2.0
    return h_allowed


def split_step(h: np.ndarray, w: np.ndarray, cur: np.ndarray, pos: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replace the failed step ``pos`` by h/8, h/8, h/4, h/2 (restarting with backward Euler); the step after
    keeps BDF2 only if its step ratio stays ≤ 2.4 (zero-stable), else it restarts too."""
    hb = h[pos]
    parts = np.array([hb / 8, hb / 8, hb / 4, hb / 2])
    h = np.concatenate([h[:pos], parts, h[pos + 1 :]])
    w = np.concatenate([w[:pos], [0.0, 1.0, 2.0, 2.0], w[pos + 1 :]])
    cur = np.concatenate([cur[:pos], np.repeat(cur[pos], 4), cur[pos + 1 :]])
    if pos + 4 < w.size and w[pos + 4] != 0.0:
        ratio = h[pos + 4] / parts[-1]
        w[pos + 4] = ratio if ratio <= 2.4 else 0.0
    return h, w, cur


def schedule(t: np.ndarray, I_dis: np.ndarray, i_1c: float, s: Settings) -> Schedule:
    """Steps aligned with every sample, so a current step is never straddled (zero-order hold)."""
    hs: list[float] = []
    ws: list[float] = []
    cs: list[float] = []
    ends: list[int] = []
    h_allowed = s.dt_first
    h_prev = 0.0
    for k in range(len(t) - 1):
        restart = k == 0 or abs(I_dis[k] - I_dis[k - 1]) > max(s.refine_rate * i_1c, 1e-12 * i_1c)
        if restart:
            h_allowed = s.dt_first
        remaining = float(t[k + 1] - t[k])
        while remaining > 1e-12 * max(1.0, float(t[k + 1])):
            h = next_step(remaining, h_allowed)
            w = 0.0 if restart or h_prev == 0.0 else h / h_prev
            hs.append(h)
            ws.append(w)
            cs.append(float(I_dis[k]))
            restart = False
            remaining -= h
            h_prev = h
            h_allowed = min(h * s.growth, s.dt_max)
        ends.append(len(hs) - 1)
    return Schedule(np.array(hs), np.array(ws), np.array(cs), np.array(ends, dtype=int))


# ---------------------------------------------------------------------------------------------------------
# the run


@dataclass
class Trajectory:
    """Raw solver output at the sample times (model convention: current positive = discharge)."""

    voltage: np.ndarray
    T1: np.ndarray
    T2: np.ndarray
    sto_min: np.ndarray
    sto_max: np.ndarray
    dV: np.ndarray | None
    dT2: np.ndarray | None
    n_samples: int
    ended_by: str | None
    n_steps: int
    final_state: np.ndarray
    seconds: float
    newton_iterations: int = 0


def initial_state(model: DFN, soc0: float, theta_bar: np.ndarray, T0: float) -> np.ndarray:
    """Differential state at rest: uniform particle stoichiometries at soc0, c_e = c_e0, T = T0."""
    lay = model.layout
    sl = lay.slices()
    sto_n, sto_p = model.cell.stoichiometry(soc0)
    ce0 = parameters.SPECS["c_e0"].denormalise(float(theta_bar[parameters.NAMES.index("c_e0")]))
    x = np.zeros(lay.nx)
    x[sl["sn"]] = sto_n
    x[sl["sp"]] = sto_p
    x[sl["ce"]] = ce0 / C_SCALE
    x[sl["T1"]] = T0 - model.T_ref
    x[sl["T2"]] = T0 - model.T_ref
    return x


def guess_algebraic(model: DFN, x: np.ndarray, I_dis: float) -> np.ndarray:
    """A starting point for the algebraic Newton solve: equilibrium potentials, uniform reaction."""
    cell, lay = model.cell, model.layout
    sl = lay.slices()
    sn = float(np.mean(x[sl["sn"]]))
    sp = float(np.mean(x[sl["sp"]]))
    Un, Up = float(cell.fn("U_n", sn)), float(cell.fn("U_p", sp))
    z = np.zeros(lay.nz)
    off = lay.nx
    z[sl["phis_n"].start - off : sl["phis_n"].stop - off] = 0.0
    z[sl["phis_p"].start - off : sl["phis_p"].stop - off] = Up - Un
    z[sl["phie"].start - off : sl["phie"].stop - off] = -Un
    A = float(cell["A"])
    for e, sign in (("n", 1.0), ("p", -1.0)):
        a = 3.0 * float(cell[f"eps_s_{e}"]) / float(cell[f"R_s_{e}"])
        z[sl[f"i_{e}"].start - off : sl[f"i_{e}"].stop - off] = sign * I_dis / (A * a * float(cell[f"L_{e}"]))
    return z


def run(
    comp: Compiled,
    t: np.ndarray,
    I_dis: np.ndarray,
    T_amb: float,
    theta_bar: np.ndarray,
    soc0: float,
    T0: float,
    E: np.ndarray | None,
    settings: Settings,
    limits: dict[str, float],
) -> Trajectory:
    """Integrate over the samples ``t`` with zero-order-hold current ``I_dis`` (positive = discharge).

    A step whose Newton iteration fails is split (h/8, h/8, h/4, h/2, restarting with backward Euler) and
    retried from the last converged state; only a step shorter than 1 µs that still fails ends the run.
    """
    t_start = time.perf_counter()
    model = comp.model
    lay = model.layout
    nx, ns, N = lay.nx, comp.ns, comp.chunk
    cell = model.cell
    sch = schedule(t, I_dis, float(cell["Q_nom"]), settings)
    h, w, cur, sample_step = (a.copy() for a in (sch.h, sch.w, sch.current, sch.sample_step))
    n_samp = len(t)
    V, T1, T2, smin, smax = (np.full(n_samp, np.nan) for _ in range(5))
    dV = np.full((n_samp, ns), np.nan) if ns else None
    dT2 = np.full((n_samp, ns), np.nan) if ns else None
    th = ca.DM(theta_bar)
    Edm = ca.DM(E) if ns else None

    x0 = initial_state(model, soc0, theta_bar, T0)
    z0 = np.array(comp.alg(guess_algebraic(model, x0, I_dis[0]), x0, [I_dis[0], T_amb], th)).ravel()
    S0 = np.zeros((nx, ns))
    if ns:
        spec = parameters.SPECS["c_e0"]
        S0[lay.slices()["ce"], :] = (spec.upper - spec.lower) / C_SCALE * E[parameters.NAMES.index("c_e0"), :]

    def record(idx: np.ndarray, X: np.ndarray, Z: np.ndarray, Is: np.ndarray, SXs: list[np.ndarray] | None) -> None:
        m = len(idx)
        pad = N - m
        Xp = np.hstack([X, np.repeat(X[:, -1:], pad, axis=1)])
        Zp = np.hstack([Z, np.repeat(Z[:, -1:], pad, axis=1)])
        UA = np.vstack([np.concatenate([Is, np.repeat(Is[-1:], pad)]), np.full(N, T_amb)])
        if ns:
            SXp = np.hstack(SXs + [SXs[-1]] * pad)
            _, o, sv, st = comp.out(Zp, Xp, UA, th, SXp, Edm)
            dV[idx] = np.array(sv).reshape(ns, N, order="F").T[:m]
            dT2[idx] = np.array(st).reshape(ns, N, order="F").T[:m]
        else:
            _, o = comp.out(Zp, Xp, UA, th)
        V[idx], T1[idx], T2[idx], smin[idx], smax[idx] = np.array(o)[:, :m]

    record(np.array([0]), x0[:, None], z0[:, None], np.array([I_dis[0]]), [S0] if ns else None)
    ended_by = _check(0, V, T2, smin, smax, limits)
    last_sample = 0
    y = np.concatenate([x0, z0])
    xp = x0.copy()
    S, Sp = S0.copy(), S0.copy()
    pos = 0
    while ended_by is None and pos < len(h):
        m = min(N, len(h) - pos)
        U = np.empty((4, N))
        U[0, :m], U[1, :m], U[2, :m] = h[pos : pos + m], w[pos : pos + m], cur[pos : pos + m]
        U[0, m:], U[1, m:], U[2, m:] = 0.0, 0.0, cur[pos + m - 1]  # zero-length padding: no effect
        U[3, :] = T_amb
        if ns:
            Y, XP, SS, SSP, RES = comp.step(y, xp, S, Sp, U, th, Edm)
            SS, SSP = np.array(SS), np.array(SSP)
        else:
            Y, XP, RES = comp.step(y, xp, U, th)
        Y, XP = np.array(Y), np.array(XP)
        bad = np.flatnonzero(~(np.array(RES).ravel()[:m] < NEWTON_FAIL))
        m_ok = int(bad[0]) if bad.size else m
        sel = np.flatnonzero((sample_step >= pos) & (sample_step < pos + m_ok))
        if sel.size:
            cols = sample_step[sel] - pos
            samples = sel + 1
            SXs = [SS[:, c * ns : (c + 1) * ns] for c in cols] if ns else None
            record(samples, Y[:nx, cols], Y[nx:, cols], I_dis[samples], SXs)
            for k in samples:
                ended_by = _check(k, V, T2, smin, smax, limits)
                if ended_by is not None:
                    break
                last_sample = k
        if ended_by is not None:
            break
        if m_ok > 0:
            y, xp = Y[:, m_ok - 1], XP[:, m_ok - 1]
            if ns:
                S, Sp = SS[:, (m_ok - 1) * ns : m_ok * ns], SSP[:, (m_ok - 1) * ns : m_ok * ns]
        pos += m_ok
        if bad.size:  # split the failed step and retry it
            hb = h[pos]
            if hb < 1e-6:
                ended_by = f"solver: Newton did not converge at t = {float(np.sum(h[:pos])):.6g} s"
                break
            h, w, cur = split_step(h, w, cur, pos)
            sample_step = np.where(sample_step >= pos, sample_step + 3, sample_step)
    n_keep = last_sample + 1
    return Trajectory(
        V[:n_keep],
        T1[:n_keep],
        T2[:n_keep],
        smin[:n_keep],
        smax[:n_keep],
        None if dV is None else dV[:n_keep],
        None if dT2 is None else dT2[:n_keep],
        n_keep,
        ended_by,
        len(h),
        y,
        time.perf_counter() - t_start,
    )


def _check(
    k: int, V: np.ndarray, T2: np.ndarray, smin: np.ndarray, smax: np.ndarray, limits: dict[str, float]
) -> str | None:
    """Why the run must stop at sample k, or None."""
    if not (np.isfinite(V[k]) and np.isfinite(T2[k])):
        return "solver: no converged solution (state left the model's domain)"
    if V[k] < limits["V_min"]:
        return f"V < {limits['V_min']:g}"
    if V[k] > limits["V_max"]:
        return f"V > {limits['V_max']:g}"
    if T2[k] > limits["T_max"]:
        return f"T_surface > {limits['T_max'] - 273.15:g} degC"
    if smin[k] <= 0.0:
        return "surface stoichiometry reached 0"
    if smax[k] >= 1.0:
        return "surface stoichiometry reached 1"
    return None


# ---------------------------------------------------------------------------------------------------------
# the compiled stepper


_NATIVE: dict[tuple, object] = {}


def native_stepper(cell: Cell, mesh: Mesh, isothermal: bool):  # -> NativeStepper
    """The compiled stepper of (cell, mesh, thermal option), built once per process (and cached on disk)."""
    from battlab.model.native import NativeStepper

    key = (cell.static_hash(), mesh, isothermal)
    if key not in _NATIVE:
        _NATIVE[key] = NativeStepper(DFN(cell, mesh, isothermal=isothermal))
    return _NATIVE[key]


def run_native(
    stepper,
    t: np.ndarray,
    I_dis: np.ndarray,
    T_amb: float,
    theta_bar: np.ndarray,
    soc0: float,
    T0: float,
    sel: list[int],
    settings: Settings,
    limits: dict[str, float],
) -> Trajectory:
    """As :func:`run`, on the compiled stepper: one C call for the whole profile (plus retries)."""
    t_start = time.perf_counter()
    model = stepper.model
    lay = model.layout
    nx, ns = lay.nx, len(sel)
    sch = schedule(t, I_dis, float(model.cell["Q_nom"]), settings)
    n_samp = len(t)
    # zero-length first steps find the consistent algebraic state at t = 0 by continuation in the current
    # from rest (where the equilibrium guess is exact), the last one writes sample 0
    ramp = I_dis[0] * np.array([0.0, 0.125, 0.25, 0.5, 1.0])
    n0 = ramp.size
    h = np.concatenate([np.zeros(n0), sch.h])
    w = np.concatenate([np.zeros(n0), sch.w])
    cur = np.concatenate([ramp, sch.current])
    out_idx = np.full(h.size, -1, dtype=np.int32)
    out_I = np.zeros(h.size)
    out_idx[n0 - 1], out_I[n0 - 1] = 0, I_dis[0]
    out_idx[sch.sample_step + n0] = np.arange(1, n_samp)
    out_I[sch.sample_step + n0] = I_dis[1:]
    out = np.full((n_samp, 5), np.nan)
    outdV = np.full((n_samp, max(ns, 1)), np.nan)
    outdT2 = np.full((n_samp, max(ns, 1)), np.nan)
    th = np.asarray(theta_bar, float)
    x0 = initial_state(model, soc0, th, T0)
    y = np.concatenate([x0, guess_algebraic(model, x0, 0.0)])
    xp = x0.copy()
    S = np.zeros((nx, ns))  # C layout: row-major, S[i, j] = dx_i/dθ̄_sel[j]
    if ns:
        spec = parameters.SPECS["c_e0"]
        k_ce = parameters.NAMES.index("c_e0")
        for j, s in enumerate(sel):
            if s == k_ce:
                S[lay.slices()["ce"], j] = (spec.upper - spec.lower) / C_SCALE
    Sp = S.copy()
    lim = np.array([limits["V_min"], limits["V_max"], limits["T_max"]])
    if not stepper.analysed:
        stepper.analyse_at(y, x0, x0, np.array([1.0, 0.0, I_dis[0] or float(model.cell["Q_nom"]), T_amb]), th)
    pos = 0
    ended_by = None
    n_iter = 0
    reanalysed = -1
    while pos < h.size:
        sl_ = slice(pos, None)
        done, code, it = stepper.run(
            h[sl_],
            w[sl_],
            cur[sl_],
            np.full(h.size - pos, T_amb),
            out_idx[sl_],
            out_I[sl_],
            th,
            np.array(sel, dtype=np.int32),
            y,
            xp,
            S,
            Sp,
            out,
            outdV,
            outdT2,
            lim,
        )
        n_iter += it
        pos += done
        if code == 0:
            break
        if code == 1:
            k = int(out_idx[pos - 1])
            ended_by = _check(k, out[:, 0], out[:, 2], out[:, 3], out[:, 4], limits)
            break
        if code == -4:
            ended_by = f"solver: no right-limit solution at t = {float(np.sum(h[:pos])):.6g} s"
            break
        # a failed step: y, xp, S, Sp hold the last converged state; first a pivot order for this state,
        # then smaller steps
        if reanalysed != pos:
            stepper.analyse_at(y, y[:nx], xp, np.array([max(h[pos], 1e-3), w[pos], cur[pos], T_amb]), th)
            reanalysed = pos
            continue
        hb = h[pos]
        if hb < 1e-6:
            ended_by = f"solver: Newton did not converge at t = {float(np.sum(h[:pos])):.6g} s"
            break
        h, w, cur = split_step(h, w, cur, pos)
        out_idx = np.concatenate([out_idx[:pos], [-1, -1, -1], out_idx[pos:]])
        out_I = np.concatenate([out_I[:pos], [0.0, 0.0, 0.0], out_I[pos:]])
    # samples written before the stop
    written = out_idx[:pos][out_idx[:pos] >= 0]
    n_keep = int(written.max()) + 1 if written.size else 0
    if ended_by is not None and ended_by.startswith(("V ", "T_", "surface", "solver: no right-limit")):
        n_keep -= 1  # the sample beyond the limit (or without a solution) is not part of the result
    V, T1, T2, smin, smax = (out[:n_keep, j] for j in range(5))
    return Trajectory(
        V,
        T1,
        T2,
        smin,
        smax,
        outdV[:n_keep] if ns else None,
        outdT2[:n_keep] if ns else None,
        n_keep,
        ended_by,
        int(h.size - 1),
        y,
        time.perf_counter() - t_start,
        n_iter,
    )
