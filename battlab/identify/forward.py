"""The forward model as the fit sees it: voltage and exact sensitivities dV/dθ̄ at a vector of normalised values.

``battlab.simulate`` takes a :class:`~battlab.Cell`; a fit changes θ̄ every iteration, and a new cell costs a
model build (≈0.5 s) although the compiled stepper takes θ̄ as an input. :class:`ForwardModel` keeps the stepper
of one base cell and passes θ̄ straight to it (same solver, same limits, same sign conversion as
``battlab.simulate``; a test checks they agree). Its steps end at every sample (``Settings(adaptive=False)``):
error-controlled steps would move with θ̄ and make the cost a step function at the level of the tolerance.
Without a C compiler it falls back to ``battlab.simulate``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.simulation import check_sensitivities, simulate, to_model_current
from protocols.errors import InputError
from protocols.profile import Profile


@dataclass(frozen=True)
class Output:
    """Voltage [V] at the profile's samples (may end early, see ``ended_by``) and dV/dθ̄ (n, n_sens)."""

    voltage: np.ndarray
    sensitivities: np.ndarray | None
    ended_by: str | None
    T_surface: np.ndarray | None = None


class ForwardModel:
    """Simulate ``cell`` with its identified values replaced by a θ̄ vector (in ``cell.parameter_names()``
    order: the 18 of :data:`parameters.NAMES`, then its extensions' ``KEY.NAME``)."""

    def __init__(self, cell: Cell, *, isothermal: bool = False, v_margin: float = 0.0) -> None:
        self.cell = cell
        self.v_margin = float(v_margin)  # widen the voltage stop [V] (measured data may exceed the window)
        self.isothermal = isothermal
        self.names = cell.parameter_names()  # θ̄'s order: the 18, then the extensions' KEY.NAME
        self.theta0 = cell.theta_bar()
        self._stepper = None
        self._native_ok: bool | None = None

    def cell_at(self, theta_bar: np.ndarray) -> Cell:
        """The cell with all identified parameters set from ``theta_bar``."""
        return self.cell.with_normalised(**dict(zip(self.names, map(float, theta_bar), strict=True)))

    def theta_of(self, cell: Cell) -> np.ndarray:
        """θ̄ of ``cell``, which must differ from the base cell in dynamic values only."""
        if cell is not self.cell:
            fixed = set(self.cell.values) - set(parameters.NAMES)
            diff = sorted(
                k
                for k in fixed | (set(cell.values) - set(parameters.NAMES))
                if repr(cell.get(k)) != repr(self.cell.get(k))
            )
            if list(cell.extensions) != list(self.cell.extensions):
                diff.append(f"extensions {list(cell.extensions)}")
            if diff:
                raise InputError(
                    f"cell {cell.name!r} differs from the model's base cell {self.cell.name!r} in non-dynamic "
                    f"values {diff[:5]}: build a ForwardModel for it"
                )
        return cell.theta_bar()

    @property
    def thread_safe(self) -> bool:
        """Whether :meth:`run` may be called from several threads at once (the compiled stepper: it releases
        the GIL and keeps its work memory per thread; the CasADi fallback is run on one thread)."""
        return self._native() is not None

    def _native(self):  # -> NativeStepper | None
        if self._native_ok is None:
            from battlab.model import solver
            from battlab.model.mesh import Mesh
            from battlab.model.native import NativeUnavailable

            try:
                self._stepper = solver.native_stepper(self.cell, Mesh(), self.isothermal)
                self._native_ok = True
            except NativeUnavailable:
                self._native_ok = False
        return self._stepper if self._native_ok else None

    def run(
        self,
        theta_bar: np.ndarray,
        profile: Profile,
        soc0: float,
        *,
        ambient: float = 298.15,
        T0: float | None = None,
        sensitivities: Sequence[str] = (),
    ) -> Output:
        """Voltage and dV/dθ̄ for the named parameters under ``profile`` from rest at ``soc0``."""
        names = check_sensitivities(self.cell, sensitivities)
        theta_bar = np.asarray(theta_bar, float)
        stepper = self._native()
        if stepper is None:
            lim = (float(self.cell["V_min"]) - self.v_margin, float(self.cell["V_max"]) + self.v_margin)
            res = simulate(
                self.cell_at(theta_bar),
                profile,
                soc0=soc0,
                ambient=ambient,
                isothermal=self.isothermal,
                sensitivities=names,
                T0=T0,
                v_limits=lim,
            )
            return Output(res.voltage, res.sensitivities, res.ended_by, res.T_surface)
        from battlab.model import solver

        cell = self.cell
        m = self.v_margin
        limits = {"V_min": float(cell["V_min"]) - m, "V_max": float(cell["V_max"]) + m, "T_max": float(cell["T_max"])}
        sel = [self.names.index(n) for n in names]
        t = profile.t - profile.t[0]
        traj = solver.run_native(
            stepper,
            t,
            to_model_current(profile.current),
            float(ambient),
            theta_bar,
            float(soc0),
            float(ambient if T0 is None else T0),
            sel,
            solver.Settings(adaptive=False),  # steps that do not move with θ̄: a cost smooth in θ̄
            limits,
        )
        return Output(traj.voltage, traj.dV if names else None, traj.ended_by, traj.T2)
