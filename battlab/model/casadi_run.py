"""Time integration inside CasADi (the fallback without a C compiler), with exact discrete forward
sensitivities (staggered direct method).

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
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.model.dfn import C_SCALE, DFN
from battlab.model.mesh import Mesh
from battlab.model.schedule import schedule, split_step
from battlab.model.state import (
    NEWTON_FAIL,
    NEWTON_OPTIONS,
    Settings,
    Trajectory,
    check_end,
    guess_algebraic,
    initial_state,
)


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
    th = ca.SX.sym("th", model.n_theta)
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
    TH = ca.MX.sym("TH", model.n_theta)
    rf = ca.rootfinder("rf", "newton", res, NEWTON_OPTIONS)
    y_new = rf(Y, XN, XP, U, TH)
    # history: a zero-length step (padding) leaves states and history unchanged
    live = U[0] > 0
    xp_new = ca.if_else(live, XN, XP)
    ins = [Y, XP, U, TH]
    resid = ca.norm_inf(res(y_new, XN, XP, U, TH))  # Newton failure shows here (error_on_fail is off)
    outs = [y_new, xp_new]
    if ns:
        E = ca.MX.sym("E", model.n_theta, ns)  # selects the parameters to differentiate against
        SN = ca.MX.sym("SN", nx, ns)
        SP = ca.MX.sym("SP", nx, ns)
        ysym = ca.SX.sym("y", ny)
        xns = ca.SX.sym("xn", nx)
        xps = ca.SX.sym("xp", nx)
        us = ca.SX.sym("u", 4)
        ths = ca.SX.sym("th", model.n_theta)
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
    rfa = ca.rootfinder("rfa", "newton", galg, NEWTON_OPTIONS)
    z_sol = rfa(Z, X, UA, TH)
    o = outf(z_sol, X, UA, TH)
    alg = ca.Function("alg", [Z, X, UA, TH], [z_sol])
    if ns:
        zs, xs, uas, ths2 = ca.SX.sym("z", nz), ca.SX.sym("x", nx), ca.SX.sym("ua", 2), ca.SX.sym("th", model.n_theta)
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
        E2 = ca.MX.sym("E", model.n_theta, ns)
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
    sch = schedule(t, I_dis, float(cell["Q_nom"]), replace(settings, across_samples=False))  # steps end at samples
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
    ended_by = check_end(0, V, T2, smin, smax, limits)
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
                ended_by = check_end(k, V, T2, smin, smax, limits)
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
