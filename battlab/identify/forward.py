"""The forward model as the fit sees it: voltage and exact sensitivities dV/dθ̄ at a vector of normalised values.

``battlab.simulate`` takes a :class:`~battlab.Cell`; a fit changes θ̄ every iteration, and a new cell costs a
model build (≈0.5 s) although the compiled stepper takes θ̄ as an input. :class:`ForwardModel` keeps the stepper
of one base cell and passes θ̄ straight to it (same solver, same limits, same sign conversion as
``battlab.simulate``; a test checks they agree). Its steps end at every sample (``Settings(adaptive=False)``,
restarting with a :data:`DT_FIRST` step where the current changes, or with a step of the tester's set-to-sample delay
``sample_delay`` before the sample where the log says the current changed that much earlier):
error-controlled steps would move with θ̄ and make the cost a step function at the level of the tolerance.
Without a C compiler it falls back to ``battlab.simulate``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.simulation import check_sensitivities, simulate, to_model_current
from protocols.errors import InputError
from protocols.profile import Profile

#: The first step [s] after every change of the current (backward Euler, then BDF2 growing ×2 to the next sample).
#: Its first-order error sets the model's accuracy on profiles whose current changes at every sample: on a 1 s sine
#: (library profile 541, nca18650-true) 1/3 s gave 0.15 mV RMS from a converged solution, as much as the tester's
#: noise (0.19 mV), and a fit took it up in its parameters; 0.15 s gives about 0.03 mV in 3 steps per sample
#: instead of 2.
DT_FIRST = 0.15


@dataclass(frozen=True)
class Output:
    """Voltage [V] at the profile's samples (may end early, see ``ended_by``) and dV/dθ̄ (n, n_sens)."""

    voltage: np.ndarray
    sensitivities: np.ndarray | None
    ended_by: str | None
    T_surface: np.ndarray | None = None
    T_core: np.ndarray | None = None
    dT: np.ndarray | None = None  # dT_surface/dθ̄ (n, n_sens) [K]
    #: dV/d(start SOC) [V] and dT_surface/d(start SOC) [K] (n,): asked for with ``soc_sensitivity`` and given where
    #: the compiled stepper runs from a state at a SOC (None otherwise: the caller differences)
    dsoc: np.ndarray | None = None
    dsoc_T: np.ndarray | None = None


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
            from battlab.model.build import NativeUnavailable
            from battlab.model.mesh import Mesh

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
        start: tuple[float, float] | None = None,
        capacity: float = 1.0,
        sample_delay: float = 0.0,
        soc_sensitivity: bool = False,
    ) -> Output:
        """Voltage and dV/dθ̄ for the named parameters under ``profile`` from rest at ``soc0``.

        ``soc_sensitivity``: also dV/d(soc0) (``Output.dsoc``, exact: one more direction of the same sensitivity
        solves) where the compiled stepper runs and ``start`` is not given.

        ``sample_delay`` [s]: each sample's current took effect this long before its time stamp (the tester's
        set-to-sample delay, :class:`battlab.model.state.Settings` ``current_lead``).

        Per-file ageing (:mod:`battlab.identify.ageing`): ``start`` (θ⁻, θ⁺) replaces the stoichiometries at
        ``soc0``; ``capacity`` c scales the electrode area: the model runs at the current I/c (the same current
        densities) and the contact resistance's drop is corrected from R_c I/c to R_c I."""
        out = self._run(
            theta_bar, profile, soc0, ambient, T0, sensitivities, start, capacity, sample_delay, soc_sensitivity
        )
        return out if capacity == 1.0 else self._contact_corrected(out, theta_bar, profile, capacity, sensitivities)

    def _contact_corrected(
        self, out: Output, theta_bar: np.ndarray, profile: Profile, capacity: float, sensitivities: Sequence[str]
    ) -> Output:
        """V + R I (1/c − 1) with R = the cell's R_c plus the contact-resistance extension's R_c + dRc_dT (T₁ −
        T_ref) (model sign: I positive = discharge); that extension's sensitivity columns get the same term."""
        k = out.voltage.size
        i_dis = to_model_current(profile.current)[:k] * (1.0 / capacity - 1.0)
        r = np.full(k, float(self.cell["R_c"]))
        dV = None if out.sensitivities is None else out.sensitivities.copy()
        names = list(sensitivities)
        if "contact_resistance" in self.cell.extensions:
            th = dict(zip(self.names, map(float, theta_bar), strict=True))
            spec_r = parameters.EXTENSION_SPECS["contact_resistance.R_c"]
            spec_t = parameters.EXTENSION_SPECS["contact_resistance.dRc_dT"]
            dT = (out.T_core if out.T_core is not None else np.full(k, float(self.cell["T_ref"]))) - float(
                self.cell["T_ref"]
            )
            r += spec_r.denormalise(th[spec_r.qualified]) + spec_t.denormalise(th[spec_t.qualified]) * dT
            for spec, factor in ((spec_r, 1.0), (spec_t, dT)):
                if dV is not None and spec.qualified in names:
                    dV[:, names.index(spec.qualified)] += i_dis * factor * (spec.upper - spec.lower)
        return replace(out, voltage=out.voltage + r * i_dis, sensitivities=dV)

    def _run(
        self,
        theta_bar: np.ndarray,
        profile: Profile,
        soc0: float,
        ambient: float,
        T0: float | None,
        sensitivities: Sequence[str],
        start: tuple[float, float] | None,
        capacity: float,
        sample_delay: float,
        soc_sensitivity: bool = False,
    ) -> Output:
        names = check_sensitivities(self.cell, sensitivities)
        theta_bar = np.asarray(theta_bar, float)
        stepper = self._native()
        if capacity != 1.0:
            profile = Profile(
                profile.t, profile.current / capacity, id=profile.id, kind=profile.kind, soc0=profile.soc0
            )
        from battlab.model import solver

        # steps that do not move with θ̄: a smooth cost
        steps = solver.Settings(adaptive=False, dt_first=DT_FIRST, current_lead=float(sample_delay))
        if stepper is None:
            lim = (float(self.cell["V_min"]) - self.v_margin, float(self.cell["V_max"]) + self.v_margin)
            cell = self.cell_at(theta_bar)
            if start is not None:  # a window that is the start state at every SOC
                cell = cell.with_values(sto_n_0=start[0], sto_n_100=start[0], sto_p_0=start[1], sto_p_100=start[1])
            res = simulate(
                cell,
                profile,
                soc0=soc0,
                ambient=ambient,
                isothermal=self.isothermal,
                sensitivities=names,
                T0=T0,
                v_limits=lim,
                settings=steps,
            )
            return Output(res.voltage, res.sensitivities, res.ended_by, res.T_surface, res.T_core, res.sensitivities_T)
        cell = self.cell
        m = self.v_margin
        limits = {"V_min": float(cell["V_min"]) - m, "V_max": float(cell["V_max"]) + m, "T_max": float(cell["T_max"])}
        sel = [self.names.index(n) for n in names]
        with_soc = soc_sensitivity and start is None
        if with_soc:
            sel.append(solver.START_SOC)
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
            steps,
            limits,
            start,
        )
        k, dV, dT = len(names), traj.dV, traj.dT2  # θ̄'s columns, then the start SOC's
        soc = (dV[:, k].copy(), dT[:, k].copy()) if with_soc and dV is not None and dT is not None else (None, None)
        theta = (dV[:, :k], dT[:, :k]) if names and dV is not None and dT is not None else (None, None)
        return Output(traj.voltage, theta[0], traj.ended_by, traj.T2, traj.T1, theta[1], *soc)
