"""``battlab.simulate``: the public entry point to the DFN–thermal model.

This is the one place where the sign convention changes: the public API, files and CLI use positive = charge
(BDF), the model uses positive = discharge (the paper, PyBaMM).
"""

from __future__ import annotations

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

    @property
    def completed(self) -> bool:
        return self.ended_by is None


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
) -> Result:
    """Simulate ``cell`` under ``profile`` from rest at ``soc0`` (default: the profile's own ``soc0``).

    ambient and T0 (initial temperature, default ambient) in K. ``sensitivities``: names of dynamic
    parameters (any subset of the 18, in the order wanted). The run stops cleanly at the cell's voltage limits
    (or ``v_limits``), at its maximum surface temperature, or when a particle surface empties or fills:
    ``ended_by`` says why; the arrays then end at the last sample within limits.
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
    names = parameters.check_names(list(sensitivities))
    mesh = mesh or Mesh()
    settings = settings or solver.Settings()
    ns = len(names)
    comp = solver.compile_model(cell, mesh, isothermal, ns, settings.chunk)
    theta_bar = np.array([cell.normalised(n) for n in parameters.NAMES])
    E = np.zeros((len(parameters.NAMES), ns))
    for j, n in enumerate(names):
        E[parameters.NAMES.index(n), j] = 1.0
    vmin, vmax = v_limits or (float(cell["V_min"]), float(cell["V_max"]))
    limits = {"V_min": vmin, "V_max": vmax, "T_max": float(cell["T_max"])}
    t = profile.t - profile.t[0]
    traj = solver.run(
        comp, t, to_model_current(profile.current), float(ambient), theta_bar, soc0,
        float(ambient if T0 is None else T0), E if ns else None, settings, limits,
    )
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
        stats={"build_seconds": comp.build_seconds, "solve_seconds": traj.seconds, "steps": traj.n_steps},
    )
