"""The PyBaMM side of the model benchmarks: test profiles, the exact zero-order-hold current for PyBaMM
(a balanced sum of Heaviside steps), the BPX cell in PyBaMM and its converged reference solution."""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from table import log

ROOT = Path(__file__).resolve().parents[1]
BPX = Path(os.environ.get("BATTLAB_DATA", ROOT.parent / "shared" / "data")) / "bpx" / "nmc_pouch_cell_BPX.json"
FINE = {k: 60 for k in ("x_n", "x_s", "x_p", "r_n", "r_p")}
RIGHT = 1e-6  # s after a current step: PyBaMM's right limit
WIDE = (2.0, 4.6)  # V, robustness runs
SENS9 = ("D_s_n", "D_s_p", "sigma_n", "sigma_p", "D_e_scale", "kappa_scale", "t_plus", "k_n", "k_p")


# ---------------------------------------------------------------------------------------------------------------
# profiles
def udds_current(duration: float, scale: float) -> np.ndarray:
    """UDDS cell current [A] (positive = charge) at 1 s samples over ``duration`` s, × ``scale``."""
    from protocols import Cycle, drive_profile

    base = drive_profile(Cycle.UDDS).current[:-1]
    cur = scale * np.resize(base, int(duration) + 1)
    cur[-1] = cur[-2]  # the last sample has no duration: hold the last value (PyBaMM reads the left limit there)
    return cur


def sine_profile(amplitude: float, duration: float = 3600.0) -> Any:
    from protocols import Profile

    t = np.arange(0.0, duration + 1.0)
    return Profile(t, amplitude * np.sin(2.0 * np.pi * 0.1 * t))


def pulse_trains(one_c: float, widths: tuple[float, ...], rates: tuple[float, ...]) -> list[tuple[str, Any, float]]:
    """As tests/battlab/test_simulate.py: pulse + equal rest, within the SOC window, 120–3600 s."""
    from protocols import Profile

    out = []
    for w in widths:
        for c in rates:
            amp = c * one_c
            n = int(min(max(120.0, 20.0 * w), 3600.0) // (2.0 * w))
            n = min(n, int(0.6 * 3600.0 * one_c // (amp * w)))
            if n < 1:
                continue
            for kind, soc0 in (("discharge", 0.8), ("charge", 0.2), ("bipolar", 0.5)):
                if kind == "bipolar":
                    durs, curs = np.tile([w / 2, w / 2, w], n), np.tile([-amp, amp, 0.0], n)
                else:
                    durs, curs = np.tile([w, w], n), np.tile([amp if kind == "charge" else -amp, 0.0], n)
                out.append((f"{kind} {w:g} s {c:g}C", Profile.from_segments(durs, curs), soc0))
    return out


# ---------------------------------------------------------------------------------------------------------------
# PyBaMM helpers
def pybamm_zoh(t: np.ndarray, current: np.ndarray) -> Any:
    """Zero-order-hold current (PyBaMM's sign, positive = discharge), exactly: I_0 + Σ ΔI_k H(t − t_k), summed as a
    balanced tree (a chain of thousands of terms overflows PyBaMM's recursive tree walks)."""
    import pybamm

    i_dis = -np.asarray(current, float)
    terms = [pybamm.Scalar(float(i_dis[0]))]
    for d, tk in zip(np.diff(i_dis[:-1]), t[1:-1], strict=True):
        if d != 0.0:
            terms.append(pybamm.Scalar(float(d)) * (pybamm.t >= pybamm.Scalar(float(tk))))
    while len(terms) > 1:
        terms = [terms[i] + terms[i + 1] if i + 1 < len(terms) else terms[i] for i in range(0, len(terms), 2)]
    return terms[0]


def right_limits(t: np.ndarray) -> np.ndarray:
    """PyBaMM query times for battlab's right limits at the samples."""
    return np.concatenate([[t[0]], t[1:-1] + RIGHT, [t[-1]]])


#: PyBaMM reference tolerances (rtol, atol), tightest first: at 60 points IDAKLU with atol 1e-10 fails on the UDDS
#: current (IDA_CONV_FAIL at t = 64 s, a discharge-to-charge step), so the reference falls back to the next pair.
TIGHT = ((1e-8, 1e-10), (1e-8, 1e-8), (1e-7, 1e-9))


def pybamm_bpx(
    soc0: float, current: Any, var_pts: dict[str, int] | None, tol: tuple[float, float] | None = None
) -> Any:
    """PyBaMM's DFN on the BPX cell from ``soc0``; ``tol`` = (rtol, atol) for IDAKLU, None for its defaults."""
    import pybamm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pv = pybamm.ParameterValues.create_from_bpx(str(BPX), target_soc=soc0)
    pv["Current function [A]"] = current
    solver = pybamm.IDAKLUSolver(rtol=tol[0], atol=tol[1]) if tol else pybamm.IDAKLUSolver()
    return pybamm.Simulation(pybamm.lithium_ion.DFN(), parameter_values=pv, var_pts=var_pts, solver=solver)


def solve_reference(t: np.ndarray, current: np.ndarray, soc0: float) -> tuple[np.ndarray, np.ndarray, float, str]:
    """PyBaMM converged (60 points, tight tolerances) on the BPX cell: (t, V) at right limits up to the cut-off,
    wall time, and the tolerances that succeeded."""
    import pybamm

    q = right_limits(t)
    for rtol, atol in TIGHT:
        sim = pybamm_bpx(soc0, pybamm_zoh(t, current), FINE, (rtol, atol))
        t0 = time.perf_counter()
        try:
            sol = sim.solve([float(t[0]), float(t[-1])], t_interp=q)
        except pybamm.SolverError as exc:
            log(f"   PyBaMM failed at rtol {rtol:g}, atol {atol:g}: {str(exc)[:90]}")
            continue
        wall = time.perf_counter() - t0
        n = int(np.searchsorted(q, sol.t[-1], side="right"))
        return t[:n], np.asarray(sol["Voltage [V]"](q[:n])), wall, f"rtol {rtol:g}, atol {atol:g}"
    raise RuntimeError("PyBaMM's reference failed at every tolerance tried")


def check_zoh(duration: float = 120.0) -> float:
    """Max |ΔV| [V] between the Heaviside current and a step-by-step PyBaMM solve (current as an input parameter,
    one ``solver.step`` per sample), read mid-interval, on the first ``duration`` s of the UDDS profile."""
    import pybamm

    t = np.arange(0.0, duration + 1.0)
    cur = udds_current(duration, 12.5 / 2.7)
    mid = t[:-1] + 0.5
    sim = pybamm_bpx(0.8, pybamm_zoh(t, cur), {k: 20 for k in FINE}, TIGHT[0])
    v_h = sim.solve([0.0, float(t[-1])], t_interp=np.union1d(t, mid))["Voltage [V]"](mid)
    step_sim = pybamm_bpx(0.8, pybamm.InputParameter("I"), {k: 20 for k in FINE}, TIGHT[0])
    step_sim.build()
    solver, sol = step_sim.solver, None
    for k in range(t.size - 1):
        sol = solver.step(sol, step_sim.built_model, 1.0, t_eval=np.array([0.0, 0.5, 1.0]), inputs={"I": -cur[k]})
    return float(np.max(np.abs(v_h - sol["Voltage [V]"](mid))))


def rmse_mV(t_a: np.ndarray, v_a: np.ndarray, t_b: np.ndarray, v_b: np.ndarray) -> float:
    _, ia, ib = np.intersect1d(np.round(t_a, 9), np.round(t_b, 9), return_indices=True)
    return float(1e3 * np.sqrt(np.mean((v_a[ia] - v_b[ib]) ** 2)))


# ---------------------------------------------------------------------------------------------------------------
# battlab's extensions as PyBaMM options
def hysteresis_in_pybamm(U: Any, M: float, gamma: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """PyBaMM's options and values for battlab's hysteresis on the negative electrode (half-width ``M`` [V], decay
    rate ``gamma``, h₀ = 0): one-state hysteresis with branches U ∓ M and equal decay rates; ``U`` is PyBaMM's
    negative OCP function."""
    values = {
        "Negative electrode lithiation OCP [V]": lambda sto: U(sto) - M,
        "Negative electrode delithiation OCP [V]": lambda sto: U(sto) + M,
        "Negative particle lithiation hysteresis decay rate": lambda sto, T: gamma,
        "Negative particle delithiation hysteresis decay rate": lambda sto, T: gamma,
        "Initial hysteresis state in negative electrode": 0.0,
    }
    return {"open-circuit potential": ("one-state hysteresis", "single")}, values


#: the SEI OCP [V] of PyBaMM's reaction-limited model (Chen 2020's value, as PyBaMM's examples use it)
U_SEI = 0.4


def capacity_fade_in_pybamm(
    cell: Any, T: float, I_side: float, alpha_side: float, lam_n: float = 0.0, lam_p: float = 0.0
) -> tuple[dict[str, Any], dict[str, Any]]:
    """PyBaMM's options and values for battlab's capacity_fade on ``cell`` at temperature ``T`` [K]: the
    reaction-limited SEI (asymmetric, transfer coefficient ``alpha_side``) with exchange current density
    j0 = I_side / (a A L⁻) · exp(−α F/(R T) (U_sei − U_ref)), no film resistance (resistivity 0: the film's drop also
    leaves the SEI overpotential) and no activation energy; the "current-driven" loss of active material at the
    constant rates dε_s/dt = −ε_s⁰ lam/3600. The SEI's thickness, volume and lithium ratio do not act here."""
    from battlab.causes.capacity_fade import CapacityFade
    from battlab.cell import R_GAS, F

    eps_n, eps_p = float(cell["eps_s_n"]), float(cell["eps_s_p"])
    area = 3.0 * eps_n / float(cell["R_s_n"]) * float(cell["A"]) * float(cell["L_n"])  # a A L⁻ [m²]
    j0 = I_side / area * np.exp(-alpha_side * F / (R_GAS * T) * (U_SEI - CapacityFade.U_ref))
    values = {
        "Ratio of lithium moles to SEI moles": 2.0,
        "SEI partial molar volume [m3.mol-1]": 9.585e-05,
        "SEI resistivity [Ohm.m]": 0.0,
        "SEI open-circuit potential [V]": U_SEI,
        "Initial SEI thickness [m]": 5e-09,
        "SEI growth activation energy [J.mol-1]": 0.0,
        "SEI growth transfer coefficient": alpha_side,
        "SEI reaction exchange current density [A.m-2]": float(j0),
        "Negative electrode current-driven LAM rate": lambda i, T: -eps_n * lam_n / 3600.0 + 0.0 * i,
        "Positive electrode current-driven LAM rate": lambda i, T: -eps_p * lam_p / 3600.0 + 0.0 * i,
    }
    options = {
        "SEI": "reaction limited (asymmetric)",
        "SEI film resistance": "none",
        "loss of active material": "current-driven",
    }
    return options, values
