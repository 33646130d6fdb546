"""Solver settings, the raw trajectory, consistent initial states and the end-of-run checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from battlab import parameters
from battlab.model.dfn import C_SCALE, DFN
from protocols.errors import InputError

NP = len(parameters.DYNAMIC)
NEWTON_FAIL = 1e-6  #: a step whose scaled residual stays above this has failed
NEWTON_OPTIONS = {
    "abstol": 1e-9,
    "abstolStep": 1e-14,
    "max_iter": 30,
    "error_on_fail": False,
    "linear_solver": "csparse",
}


@dataclass(frozen=True)
class Settings:
    """Time-step control [s].

    Every change of the current larger than ``refine_rate`` × 1C (default: any change) restarts the scheme
    with a backward-Euler step of ``dt_first``, after which steps grow by ``growth`` up to ``dt_max``: BDF2
    carried across a kink of the solution is only first order (measured: 1.1 mV vs 0.04 mV on UDDS at 1 s
    samples). With ``dt_first`` = 1/3 s a 1 s sample of a changing current takes two steps (1/3 s backward
    Euler, 2/3 s BDF2); measured against a time-converged solution on nca18650 (RMSE / max): UDDS 0.045 / 0.20 mV
    in 4916 steps, a 0.1 Hz 1C sinusoid 0.036 / 0.061 mV in 7925 (dt_first 0.25 s: 0.025 / 0.10 mV in 7379,
    0.019 / 0.034 mV in 12249). ``chunk``: steps per call of the CasADi stepper.

    ``across_samples``: where the current does not change, steps grow across output samples and the samples are
    interpolated from the BDF2 history (quadratic through the last three solutions, the sensitivities with them);
    steps still end at every sample where the current changes. False: every sample ends a step (the CasADi stepper
    and the live cell always step this way). The step sizes never depend on θ̄, so the sensitivities stay the exact
    derivatives of the discrete solution.

    ``adaptive`` (the default for the compiled stepper): the steps follow the solution. One segment per stretch of
    constant current (restarted as above where the current changes); inside it, variable-step BDF2 with a local
    error estimate (the solution's distance from the quadratic extrapolation of the last three, on the
    differential states, weighted by 1/(``atol`` + ``rtol``·|x|)), steps up to ``h_max``, samples interpolated
    from the history. The sensitivities are those of the steps taken (the step sizes held fixed); the accepted
    steps are returned (``Trajectory.steps``) and ``replay`` runs exactly those steps again, e.g. at a perturbed
    θ̄ for finite differences. Measured on nca18650 at 1C (1 s samples, against a time-converged solution):
    430 steps instead of 3706, 0.05 mV RMSE, 0.7 mV at most in the knee. The CasADi stepper ignores it.

    ``current_lead`` [s]: each sample's current took effect this long before the sample's time stamp, so that its
    voltage was read that long after the change (a host-paced tester sets the current, then measures: its
    set-to-sample delay). Steps aligned with the samples only (``adaptive`` and ``across_samples`` False): the
    interval before a sample whose current differs (by more than ``schedule.LEAD_MIN_C`` × 1C) ends with a
    backward-Euler step of ``current_lead`` at the new current, from which the steps grow as after any restart. 0: the
    current changes at the sample's time stamp.
    """

    dt_max: float = 10.0
    dt_first: float = 1.0 / 3.0
    growth: float = 2.0
    refine_rate: float = 0.0
    chunk: int = 128
    across_samples: bool = False
    adaptive: bool = True
    rtol: float = 1e-4
    atol: float = 1e-6
    h_max: float = 600.0
    replay: tuple[np.ndarray, ...] | None = None
    current_lead: float = 0.0


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
    steps: tuple[np.ndarray, ...] | None = None  # h, ω, I_dis, t_end of every step taken (Settings.replay)


def initial_state(
    model: DFN, soc0: float, theta_bar: np.ndarray, T0: float, sto0: tuple[float, float] | None = None
) -> np.ndarray:
    """Differential state at rest: uniform particle stoichiometries at soc0 (or ``sto0`` = (θ⁻, θ⁺)), c_e = c_e0,
    T = T0."""
    lay = model.layout
    sl = lay.slices()
    if sto0 is None:
        if not 0.0 <= soc0 <= 1.0:
            raise InputError(f"SOC must be in [0, 1], got {soc0}")
        n0, n1, p0, p1 = model.stoichiometry_window
        sto0 = (n0 + soc0 * (n1 - n0), p0 + soc0 * (p1 - p0))  # eq. 20, as Cell.stoichiometry
    sto_n, sto_p = sto0
    ce0 = parameters.SPECS["c_e0"].denormalise(float(theta_bar[parameters.NAMES.index("c_e0")]))
    x = np.zeros(lay.nx)
    x[sl["sn"]] = sto_n
    x[sl["sp"]] = sto_p
    x[sl["ce"]] = ce0 / C_SCALE
    x[sl["T1"]] = T0 - model.T_ref
    x[sl["T2"]] = T0 - model.T_ref
    for ext in model.options.extensions:
        if ext.key in sl:
            x[sl[ext.key]] = ext.initial_states(model.mesh, soc0)
    return x


def guess_algebraic(model: DFN, x: np.ndarray, I_dis: float) -> np.ndarray:
    """A starting point for the algebraic Newton solve: equilibrium potentials, uniform reaction."""
    cell, lay = model.cell, model.layout
    sl = lay.slices()
    sn = float(np.mean(x[sl["sn"]]))
    sp = float(np.mean(x[sl["sp"]]))
    Un, Up = model.ocp(sn, sp)
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


def check_end(
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
    return surface_end(float(smin[k]), float(smax[k]))


def surface_end(smin: float, smax: float) -> str | None:
    """Why a run ends when a particle surface emptied (lowest surface stoichiometry ``smin`` ≤ 0) or filled
    (highest ``smax`` ≥ 1), else None."""
    if smin <= 0.0:
        return "surface stoichiometry reached 0"
    if smax >= 1.0:
        return "surface stoichiometry reached 1"
    return None
