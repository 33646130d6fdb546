"""``battlab.simulate``: the public entry point to the DFN–thermal model.

This is the one place where the sign convention changes: the public API, files and CLI use positive = charge
(BDF), the model uses positive = discharge (the paper, PyBaMM).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.model import solver
from battlab.model.mesh import Mesh
from protocols.errors import InputError
from protocols.profile import Profile


def to_model_current(current_charge_positive: np.ndarray) -> np.ndarray:
    """Public current (positive = charge, BDF) → model current (positive = discharge)."""
    return -np.asarray(current_charge_positive, dtype=float)


@dataclass(frozen=True)
class Result:
    """Simulation output at the profile's sample times (right limits: the value at t[k] has current[k] applied).

    t [s], voltage [V], T_core and T_surface [K], current [A] (positive = charge); sensitivities (n_t, n_p):
    dV/dθ̄ and dT_surface/dθ̄ w.r.t. the normalised parameters (eq. 1) named in ``parameters``.
    """

    t: np.ndarray
    voltage: np.ndarray
    T_core: np.ndarray
    T_surface: np.ndarray
    current: np.ndarray
    parameters: tuple[str, ...] = ()
    sensitivities: np.ndarray | None = None
    sensitivities_T: np.ndarray | None = None
    ended_by: str | None = None
    stats: dict[str, float] = field(default_factory=dict)
    steps: tuple[np.ndarray, ...] | None = None  # the steps taken (h, ω, I, t_end): Settings(replay=...) repeats them

    @property
    def completed(self) -> bool:
        return self.ended_by is None


#: [V] a voltage this close to a limit is on it, not beyond
LIMIT_ROUNDOFF = 1e-9


#: the most solver steps one simulation may take (about 40 s of the compiled stepper at 36 µs a step): a profile
#: spanning more (over 10^7 s = 116 days at the default 10 s longest step) is refused, not left to run for years
MAX_STEPS = 1_000_000


def simulate(
    cell: Cell,
    profile: Profile,
    soc0: float | None = None,
    ambient: float = 298.15,
    isothermal: bool = False,
    sensitivities: Sequence[str] = (),
    *,
    mesh: Mesh | None = None,
    settings: solver.Settings | None = None,
    T0: float | None = None,
    v_limits: tuple[float, float] | None = None,
    backend: str = "auto",
) -> Result:
    """Simulate ``cell`` under ``profile`` from rest at ``soc0`` (default: the profile's own ``soc0``).

    ambient and T0 (initial temperature, default ambient) in K. ``sensitivities``: names of identified
    parameters (any subset of the 18 and the ``KEY.NAME`` of the cell's extensions, in the order wanted). The run
    stops cleanly at the cell's voltage limits (or ``v_limits``), at its maximum surface temperature, or when a
    particle surface empties or fills:
    ``ended_by`` says why; the arrays then end at the last sample within limits.

    backend: "native" (the compiled stepper; needs a C compiler), "casadi" (the same scheme inside CasADi,
    about 15× slower), or "auto" (native when a compiler is available).
    """
    if not isinstance(profile, Profile):
        raise InputError(f"expected a protocols.Profile, got {type(profile).__name__}")
    if soc0 is None:
        soc0 = profile.soc0
    if soc0 is None:
        raise InputError("no start SOC: give soc0 or a profile with soc0")
    soc0 = float(soc0)
    if not np.isfinite(soc0) or not 0.0 <= soc0 <= 1.0:
        raise InputError(f"soc0 must be in [0, 1], got {soc0}")
    if not 150.0 < ambient < 400.0:
        raise InputError(f"ambient temperature must be in K (150–400), got {ambient}")
    names = check_sensitivities(cell, sensitivities)
    if backend not in ("auto", "native", "casadi"):
        raise InputError(f"backend must be 'auto', 'native' or 'casadi', got {backend!r}")
    mesh = mesh or Mesh()
    settings = settings or solver.Settings()
    ns = len(names)
    theta_bar, all_names = _parameters(cell)
    sel = [all_names.index(n) for n in names]
    vmin, vmax = v_limits or (float(cell["V_min"]), float(cell["V_max"]))
    if not (np.isfinite(vmin) and np.isfinite(vmax) and vmin < vmax):
        raise InputError(f"v_limits must be finite with V_min < V_max, got {v_limits}")
    # a state on a limit to round-off (a rest at 100 % SOC: OCV = V_max) is within it
    limits = {"V_min": vmin - LIMIT_ROUNDOFF, "V_max": vmax + LIMIT_ROUNDOFF, "T_max": float(cell["T_max"])}
    t = profile.t - profile.t[0]
    if t[-1] / settings.dt_max > MAX_STEPS:
        raise InputError(
            f"the profile spans {t[-1]:.4g} s: more than the "
            f"{MAX_STEPS:,} solver steps of at most {settings.dt_max:g} s a simulation may take "
            f"({MAX_STEPS * settings.dt_max:.3g} s); split it"
        )
    args = (t, to_model_current(profile.current), float(ambient), theta_bar, soc0, float(ambient if T0 is None else T0))
    stepper = _native(cell, mesh, isothermal) if backend in ("native", "auto") else None
    if stepper is not None:
        build = stepper.generate_seconds + stepper.compile_seconds
        traj = solver.run_native(stepper, *args, sel, settings, limits)
    else:
        comp = solver.compile_model(cell, mesh, isothermal, ns, settings.chunk)
        build = comp.build_seconds
        E = np.zeros((len(all_names), ns))
        E[sel, np.arange(ns)] = 1.0
        traj = solver.run(comp, *args, E if ns else None, settings, limits)
    n = traj.n_samples
    return Result(
        t=profile.t[:n].copy(),
        voltage=traj.voltage,
        T_core=traj.T1,
        T_surface=traj.T2,
        current=profile.current[:n].copy(),
        parameters=names,
        sensitivities=traj.dV,
        sensitivities_T=traj.dT2,
        ended_by=traj.ended_by,
        stats={
            "build_seconds": build,
            "solve_seconds": traj.seconds,
            "steps": traj.n_steps,
            "newton_iterations": traj.newton_iterations,
        },
        steps=traj.steps,
    )


#: per cell (an immutable value): θ̄ and the names of its entries
_THETA: weakref.WeakKeyDictionary[Cell, tuple[np.ndarray, tuple[str, ...]]] = weakref.WeakKeyDictionary()


def _parameters(cell: Cell) -> tuple[np.ndarray, tuple[str, ...]]:
    """The cell's θ̄ (a read-only array) and parameter names, computed once per cell."""
    found = _THETA.get(cell)
    if found is None:
        th = cell.theta_bar()
        th.flags.writeable = False
        found = _THETA[cell] = (th, cell.parameter_names())
    return found


def check_sensitivities(cell: Cell, names: Sequence[str]) -> tuple[str, ...]:
    """Validate sensitivity names against the cell's identified parameters (the 18 and its extensions')."""
    out = parameters.check_names(list(names))
    known = cell.parameter_names()
    for n in out:
        if n not in known:
            key = n.split(".")[0]
            raise InputError(f"sensitivity {n!r}: the extension {key!r} is not on (cell.with_extension({key!r}, ...))")
    return out


def _native(cell: Cell, mesh: Mesh, isothermal: bool):  # -> NativeStepper | None
    """The compiled stepper, or None when no C compiler can build it (then the CasADi stepper runs)."""
    from battlab.model.build import NativeUnavailable

    try:
        return solver.native_stepper(cell, mesh, isothermal)
    except NativeUnavailable as exc:
        import warnings

        warnings.warn(f"compiled stepper unavailable ({exc}); using the CasADi stepper", stacklevel=3)
        return None
