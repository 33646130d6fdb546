"""Time integration with exact discrete forward sensitivities (staggered direct method).

Scheme: variable-step BDF2 on the DAE M ẏ = [f; g] (restarting with backward Euler, ω = 0, after a large current
step), every step solved by Newton to round-off. After each step the Newton matrix J = ∂R/∂y at the solution is
factorised once more and reused for all sensitivity right-hand sides:

    J S_{n+1} = −(∂R/∂x_n S_n + ∂R/∂x_{n−1} S_{n−1} + ∂R/∂θ̄),

which are the exact derivatives of the discrete solution (so they agree with finite differences of the same
scheme on the same grid). Outputs at a sample time t_k are the right limit: the algebraic states are re-solved
with the differential states at t_k and the current that starts there, with S_z = −g_z⁻¹(g_x S_x + g_θ̄).

The compiled C stepper (:mod:`battlab.model.native`) runs the whole profile in one call (:func:`run_native`);
without a C compiler the same scheme runs inside CasADi (:mod:`battlab.model.casadi_run`). This module is the
face of both: settings, schedule, state and the two runners.
"""

from __future__ import annotations

import threading
import time
import weakref

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.model.casadi_run import Compiled, compile_model, run
from battlab.model.dfn import C_SCALE, DFN
from battlab.model.mesh import Mesh
from battlab.model.plans import AdaptiveControl, SamplePlan, StepPlan
from battlab.model.schedule import Schedule, next_step, schedule, split_ends, split_step
from battlab.model.state import (
    NEWTON_FAIL,
    NP,
    Settings,
    Trajectory,
    check_end,
    guess_algebraic,
    initial_state,
    surface_end,
)

__all__ = [
    "NEWTON_FAIL",
    "NP",
    "Compiled",
    "Schedule",
    "Settings",
    "Trajectory",
    "compile_model",
    "guess_algebraic",
    "initial_state",
    "native_stepper",
    "next_step",
    "run",
    "run_native",
    "schedule",
    "split_step",
]

# ---------------------------------------------------------------------------------------------------------
# the compiled stepper


_NATIVE: dict[tuple, object] = {}
_NATIVE_BUILD = threading.Lock()
#: per cell (an immutable value) the part of the compiled model's key it gives: its static hash is a JSON dump
_STATIC: weakref.WeakKeyDictionary[Cell, str] = weakref.WeakKeyDictionary()


def native_stepper(cell: Cell, mesh: Mesh, isothermal: bool):  # -> NativeStepper
    """The compiled stepper of (cell, mesh, option set), built once per process (and cached on disk); threads
    asking at once get the same one (built on one thread: CasADi's symbolic work is not thread-safe)."""
    from battlab.model.extensions import ModelOptions
    from battlab.model.native import NativeStepper

    static = _STATIC.get(cell)
    if static is None:
        static = _STATIC[cell] = cell.static_hash()
    key = (static, mesh, ModelOptions.of(cell, isothermal))
    with _NATIVE_BUILD:
        if key not in _NATIVE:
            _NATIVE[key] = NativeStepper(DFN(cell, mesh, isothermal=isothermal))
        return _NATIVE[key]


def _no_right_limit(
    t: float,
    I_before: float,
    I_after: float,
    limits: dict[str, float],
    v_before: float = np.nan,
    sto_before: tuple[float, float] = (np.nan, np.nan),
) -> str:
    """Why a run ends when no algebraic state within the voltage limits exists for the current that starts at a
    sample (continuation in the current found none). A larger discharge (charge) current than the cell can carry
    at this state has no solution there: the voltage collapses past the limit on the way, or the voltage–current
    curve folds before the current is reached, and a tester stops at the limit. Otherwise the state before the
    change may itself be beyond a limit (``v_before``, its voltage [V]: the voltage passed the limit during the
    step), or a particle surface in it emptied or filled during the step (``sto_before``: its lowest and highest
    surface stoichiometry; the end :func:`battlab.model.state.surface_end` gives at a sample). Currents in the model's
    sign (positive = discharge)."""
    if I_after > max(I_before, 0.0):
        return (
            f"V < {limits['V_min']:g} (no solution at {-I_after:.4g} A at t = {t:.6g} s: more than the cell can carry)"
        )
    if I_after < min(I_before, 0.0):
        return (
            f"V > {limits['V_max']:g} (no solution at {-I_after:.4g} A at t = {t:.6g} s: more than the cell can take)"
        )
    lo, hi = limits["V_min"], limits["V_max"]
    if v_before < lo or v_before > hi:
        side = f"V < {lo:g}" if v_before < lo else f"V > {hi:g}"
        return f"{side} (reached during the step to t = {t:.6g} s, where the current changes to {-I_after:.4g} A)"
    if (edge := surface_end(*sto_before)) is not None:
        return f"{edge} (during the step to t = {t:.6g} s, where the current changes to {-I_after:.4g} A)"
    return f"solver: no right-limit solution at t = {t:.6g} s"


def _failure(
    stepper, y: np.ndarray, current: float, T_amb: float, th: np.ndarray, limits: dict[str, float], t: float, what: str
) -> str:
    """Why a run ends whose next step failed (``what``: the solver's message) from the last converged state ``y``
    at time ``t`` [s], reached with ``current`` [A, + = discharge]: when that state is already beyond a voltage
    limit, the voltage passed it between samples (as it collapses towards the end of what the cell can carry, where
    the solution folds and Newton fails), and a tester stops there: the limit, not a solver failure."""
    o = stepper.outputs(y, current, T_amb, th)
    lo, hi = limits["V_min"], limits["V_max"]
    if o[0] < lo or o[0] > hi:
        side = f"V < {lo:g}" if o[0] < lo else f"V > {hi:g}"
        return f"{side} (passed between samples, at t = {t:.6g} s; the solution ends just after it)"
    return what


#: ``sel`` entry of :func:`run_native` for dV/d(start SOC): a direction of the start state alone (the stepper adds
#: no dR/dθ̄ term for it)
START_SOC = -1


def _start_soc_direction(
    model: DFN, soc0: float, th: np.ndarray, T0: float, sto0: tuple[float, float] | None
) -> np.ndarray:
    """dx₀/d(SOC) of the rest state (eq. 20: the stoichiometries are linear in the SOC; a central difference is
    exact for them and covers an extension's start states)."""
    if sto0 is not None:
        raise ValueError("a start-SOC sensitivity needs the start state at a SOC, not given stoichiometries")
    h = 1e-4
    lo, hi = max(0.0, soc0 - h), min(1.0, soc0 + h)
    return (initial_state(model, hi, th, T0) - initial_state(model, lo, th, T0)) / (hi - lo)


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
    sto0: tuple[float, float] | None = None,
) -> Trajectory:
    """As :func:`run`, on the compiled stepper: one C call for the whole profile (plus retries). ``sto0``: the start
    stoichiometries (θ⁻, θ⁺) instead of the cell's at ``soc0`` (a cell whose lithium differs from its window's).
    ``sel``: the θ̄ indices of the sensitivities, :data:`START_SOC` for dV/d(soc0) (the rest state's direction,
    exact as the others)."""
    t_start = time.perf_counter()
    model = stepper.model
    lay = model.layout
    nx, ns = lay.nx, len(sel)
    n_samp = len(t)
    t_rel = t - t[0]
    # zero-length first steps find the consistent algebraic state at t = 0 by continuation in the current
    # from rest (where the equilibrium guess is exact), the last one writes sample 0
    ramp = I_dis[0] * np.array([0.0, 0.125, 0.25, 0.5, 1.0])
    n0 = ramp.size
    adaptive = settings.adaptive and settings.replay is None
    if adaptive and settings.current_lead:
        raise ValueError("Settings.current_lead needs steps aligned with the samples (adaptive=False)")
    if settings.replay is not None:  # the steps another run accepted (its ramp included)
        h, w, cur, t_end = (np.asarray(a, float) for a in settings.replay)
    elif adaptive:  # the ramp here; the steps are chosen as the run goes (below)
        h, w, cur, t_end = np.zeros(n0), np.zeros(n0), ramp, np.zeros(n0)
    else:
        sch = schedule(t, I_dis, float(model.cell["Q_nom"]), settings)
        h = np.concatenate([np.zeros(n0), sch.h])
        w = np.concatenate([np.zeros(n0), sch.w])
        cur = np.concatenate([ramp, sch.current])
        t_end = np.concatenate([np.zeros(n0), sch.t_end])
    emit = np.concatenate([np.zeros(n0 - 1), np.ones(h.size - n0 + 1)])
    tol_t = 1e-9 * np.maximum(1.0, t_rel[1:])
    inside = np.minimum(np.searchsorted(t_end, t_rel[1:] - tol_t), t_end.size - 1)  # the step of each sample
    dense = adaptive or bool(np.any(t_end[inside] > t_rel[1:] + tol_t))
    samples = SamplePlan.of(t_rel, I_dis, lay.ny, ns, dense, 3 if adaptive else 2)  # dense: samples inside steps
    out = np.full((n_samp, 5), np.nan)
    outdV = np.full((n_samp, max(ns, 1)), np.nan)
    outdT2 = np.full((n_samp, max(ns, 1)), np.nan)
    th = np.asarray(theta_bar, float)
    x0 = initial_state(model, soc0, th, T0, sto0)
    y = np.concatenate([x0, guess_algebraic(model, x0, 0.0)])
    xp = x0.copy()
    S = np.zeros((nx, ns))  # C layout: row-major, S[i, j] = dx_i/dθ̄_sel[j]
    if ns:
        spec = parameters.SPECS["c_e0"]
        k_ce = parameters.NAMES.index("c_e0")
        for j, s in enumerate(sel):
            if s == k_ce:
                S[lay.slices()["ce"], j] = (spec.upper - spec.lower) / C_SCALE
            elif s == START_SOC:
                S[:, j] = _start_soc_direction(model, soc0, th, T0, sto0)
    Sp = S.copy()
    lim = np.array([limits["V_min"], limits["V_max"], limits["T_max"]])
    pivots = stepper.base_pivots(th)
    sel_arr = np.array(sel, dtype=np.int32)
    pos = 0
    ended_by = None
    n_iter = 0
    reanalysed: tuple[int, int] = (-1, 0)
    plan = StepPlan.of(h, w, cur, np.full(h.size, T_amb), t_end, emit)
    while pos < h.size:
        done, code, it = stepper.run(pivots, plan[pos:], samples, th, sel_arr, y, xp, S, Sp, out, outdV, outdT2, lim)
        n_iter += it
        pos += done
        if code == 0:
            break
        m = samples.next
        if code == -3:
            raise RuntimeError("compiled stepper: no work memory, or a sample inside a step without its history")
        if code == 1:  # sample m broke a limit (written, not kept)
            ended_by = check_end(m, out[:, 0], out[:, 2], out[:, 3], out[:, 4], limits)
            break
        if code == -4:
            ended_by = _no_right_limit(
                float(t_end[pos - 1]), cur[pos - 1], I_dis[m], limits, out[m, 0], (out[m, 3], out[m, 4])
            )
            break
        # a failed step: y, xp, S, Sp hold the last converged state; first a pivot order for this state (this
        # run's own: later runs start from the base again), then smaller steps. -5: a zero-length solve (the
        # start, or the right limit at a current change) met the vanishing pivot
        right_limit = h[pos] > 0.0  # a -5 after a step with h > 0 comes from the right limit at its end
        if reanalysed != (pos, code):
            if code == -5:
                u0 = np.array([0.0, 0.0, I_dis[m] if right_limit else cur[pos], T_amb])
                pivots = pivots.replace(zero=stepper.analyse_zero_at(y, u0, th))
            else:
                u1 = np.array([max(h[pos], 1e-3), w[pos], cur[pos], T_amb])
                pivots = pivots.replace(step=stepper.analyse_at(y, y[:nx], xp, u1, th))
            reanalysed = (pos, code)
            continue
        if code == -5:  # still singular: the state before the step is kept, its sample not written
            if right_limit:
                ended_by = _no_right_limit(float(t_end[pos]), cur[pos], I_dis[m], limits)
            else:
                ended_by = f"solver: singular zero-length solve at t = {float(t_end[pos]):.6g} s"
            break
        hb = h[pos]
        if hb < 1e-6:
            t_fail = float(t_end[pos] - hb)
            what = f"solver: Newton did not converge at t = {t_fail:.6g} s"
            ended_by = _failure(stepper, y, cur[max(pos - 1, 0)], T_amb, th, limits, t_fail, what)
            break
        t_end = split_ends(t_end, h, pos)
        h, w, cur = split_step(h, w, cur, pos)
        emit = np.concatenate([emit[:pos], [1, 1, 1], emit[pos:]])
        plan = StepPlan.of(h, w, cur, np.full(h.size, T_amb), t_end, emit)
    accepted = (h, w, cur, t_end)
    if adaptive and ended_by is None and n_samp > 1:
        control = AdaptiveControl(
            np.array([settings.rtol, settings.atol, settings.h_max, settings.growth, settings.dt_first])
        )
        segments = _segments(t_rel, I_dis, float(model.cell["Q_nom"]), settings, T_amb)
        ended_by, it = _adaptive(
            stepper, pivots, segments, samples, control, th, sel_arr, y, xp, S, Sp, out, outdV, outdT2, lim, limits
        )
        n_iter += it
        k = control.n
        accepted = tuple(
            np.concatenate([a, b[:k]])
            for a, b in zip(accepted, (control.h, control.w, control.current, control.t_end), strict=True)
        )
    n_keep = samples.next  # the samples written and within limits
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
        int(accepted[0].size - 1),
        y,
        time.perf_counter() - t_start,
        n_iter,
        accepted,
    )


def _segments(t_rel: np.ndarray, I_dis: np.ndarray, i_1c: float, settings: Settings, T_amb: float) -> StepPlan:
    """One entry per stretch of constant current: duration, ω = 0 where it restarts the scheme, current, end."""
    n = len(t_rel) - 1
    change = np.flatnonzero(I_dis[1:n] != I_dis[: n - 1]) + 1
    a = np.concatenate([[0], change])
    b = np.concatenate([change, [n]])
    jump = np.abs(np.diff(I_dis)) > max(settings.refine_rate * i_1c, 1e-12 * i_1c)
    restart = np.concatenate([[True], jump])[a]
    return StepPlan.of(
        t_rel[b] - t_rel[a], np.where(restart, 0.0, 1.0), I_dis[a], np.full(a.size, T_amb), t_rel[b], np.ones(a.size)
    )


def _adaptive(
    stepper,
    pivots,
    segments: StepPlan,
    samples: SamplePlan,
    control: AdaptiveControl,
    th: np.ndarray,
    sel: np.ndarray,
    y: np.ndarray,
    xp: np.ndarray,
    S: np.ndarray,
    Sp: np.ndarray,
    out: np.ndarray,
    outdV: np.ndarray,
    outdT2: np.ndarray,
    lim: np.ndarray,
    limits: dict[str, float],
) -> tuple[str | None, int]:
    """Error-controlled steps over the segments (after the start); returns (why the run ended or None, Newton
    iterations). Pivot programs that vanish are re-analysed once per place, as in :func:`run_native`."""
    nx = stepper.model.layout.nx
    T_amb = float(segments.T_amb[0])
    k = 0
    n_iter = 0
    reanalysed: tuple[int, float, int] = (-1, 0.0, 0)
    while k < segments.h.size:
        done, code, it = stepper.adapt(
            pivots, segments[k:], samples, control, th, sel, y, xp, S, Sp, out, outdV, outdT2, lim
        )
        n_iter += it
        k += done
        if code == 0:
            return None, n_iter
        if code == -6:
            control.grow()
            continue
        m = samples.next
        t_now = float(control.state[0])
        if code == -3:
            raise RuntimeError("compiled stepper: no work memory")
        if code == 1:
            return check_end(m, out[:, 0], out[:, 2], out[:, 3], out[:, 4], limits), n_iter
        if code == -4:
            why = _no_right_limit(
                t_now, segments.current[k], samples.current[m], limits, out[m, 0], (out[m, 3], out[m, 4])
            )
            return why, n_iter
        last = float(control.current[control.n - 1]) if control.n else float(segments.current[k])
        if code == -1:
            what = f"solver: Newton did not converge at t = {t_now:.6g} s"
            return _failure(stepper, y, last, T_amb, th, limits, t_now, what), n_iter
        if reanalysed == (k, t_now, code):  # still singular after a new pivot order
            if code == -5:
                return _no_right_limit(t_now, segments.current[k], samples.current[m], limits), n_iter
            h_next = float(control.state[1])
            if h_next >= 4e-6:  # a smaller step from the same state, as after a Newton failure
                control.state[1] = 0.25 * h_next
                continue
            what = f"solver: singular Jacobian at t = {t_now:.6g} s"
            return _failure(stepper, y, last, T_amb, th, limits, t_now, what), n_iter
        reanalysed = (k, t_now, code)
        control.state[6] = 1.0  # the step starts from the state kept in the history (a right limit)
        if code == -5:
            u0 = np.array([0.0, 0.0, samples.current[m], T_amb])
            pivots = pivots.replace(zero=stepper.analyse_zero_at(y, u0, th))
        else:
            u1 = np.array([max(float(control.state[1]), 1e-3), 0.0, segments.current[k], T_amb])
            pivots = pivots.replace(step=stepper.analyse_at(y, y[:nx], xp, u1, th))
    return None, n_iter
