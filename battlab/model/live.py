"""A stateful cell for the virtual tester: advance by (current, dt) and read voltage and temperatures.

The same compiled stepper and step rules as :func:`battlab.simulate` (a restart after every current change,
steps growing up to ``dt_max``), applied incrementally, so a profile played through :class:`LiveCell` one sample
at a time reproduces ``simulate`` on that profile, up to where ``simulate`` ends at a voltage limit: there the live
cell holds at the limit (:meth:`LiveCell.step`).
"""

from __future__ import annotations

import numpy as np

from battlab.cell import Cell
from battlab.model import solver
from battlab.model.mesh import Mesh
from battlab.model.plans import SamplePlan, StepPlan
from protocols.errors import InputError

_EMPTY = np.zeros(0)

#: a step that fails even with a smaller first step is retried as two halves, each retried the same way, down to
#: 1/2**SPLIT_DEPTH of the step
SPLIT_DEPTH = 5
#: bisections of a step whose solution ends inside it, for the instant the voltage reaches the cell's limit (a 10 s
#: step: to 2.4 ms)
LIMIT_BISECTIONS = 12


class CellLimitError(RuntimeError):
    """The cell left its physical window (a particle surface emptied or filled): no smaller step helps."""


class LiveCell:
    """The DFN–thermal cell as a state machine. Currents in A, positive = charge; temperatures in K."""

    def __init__(
        self,
        cell: Cell,
        soc0: float,
        T0: float = 298.15,
        *,
        mesh: Mesh | None = None,
        isothermal: bool = False,
        settings: solver.Settings | None = None,
    ) -> None:
        self.cell = cell
        self.settings = settings or solver.Settings()
        self._stepper = solver.native_stepper(cell, mesh or Mesh(), isothermal)
        self._theta = cell.theta_bar()
        self.reset(soc0, T0)

    def reset(self, soc0: float, T0: float) -> None:
        """Rest at ``soc0`` and uniform temperature ``T0`` [K]."""
        if not 0.0 <= soc0 <= 1.0:
            raise InputError(f"soc0 must be in [0, 1], got {soc0}")
        model = self._stepper.model
        x0 = solver.initial_state(model, soc0, self._theta, T0)
        self._y = np.concatenate([x0, solver.guess_algebraic(model, x0, 0.0)])
        self._xp = x0.copy()
        self._pivots = self._stepper.base_pivots(self._theta)  # re-analyses stay with this cell until reset
        self._I_dis = 0.0
        self._h_prev = 0.0
        self._h_allowed = self.settings.dt_first
        #: (discharge current [A], state where that step began) while the cell is held at its voltage limit
        self._held: tuple[float, tuple] | None = None
        self.t = 0.0
        self.voltage, self.T_core, self.T_surface = self._advance(0.0, 0.0, T0, first=True)

    def _advance(self, I_dis: float, dt: float, ambient: float, first: bool = False) -> tuple[float, float, float]:
        """Advance; a step that fails is retried from the same state, restarting with a 4× and then 16× smaller
        first step."""
        saved = (self._y.copy(), self._xp.copy(), self._I_dis, self._h_prev, self._h_allowed)
        for attempt in range(3):
            try:
                dt_first = None if attempt == 0 else self.settings.dt_first / 4**attempt
                return self._advance_once(I_dis, dt, ambient, first, dt_first)
            except RuntimeError:
                if attempt == 2:
                    raise
                self._y, self._xp = saved[0].copy(), saved[1].copy()
                self._I_dis, self._h_prev, self._h_allowed = saved[2:]
        raise AssertionError("unreachable")

    def _advance_once(
        self, I_dis: float, dt: float, ambient: float, first: bool, dt_first: float | None
    ) -> tuple[float, float, float]:
        s = self.settings
        changed = not first and I_dis != self._I_dis
        restart = first or changed or dt_first is not None
        # a current change starts with its right limit, as in simulate: a zero-length step at the old current whose
        # sample carries the new one, so the stepper solves the algebraic jump (by continuation in the current where
        # Newton from the old current's state does not converge) before the first step
        hs: list[float] = [0.0] if first or changed else []
        ws: list[float] = [0.0] if first or changed else []
        if restart:
            self._h_allowed = s.dt_first if dt_first is None else dt_first
        remaining = dt
        h_prev = 0.0 if restart else self._h_prev
        while remaining > 1e-12 * max(1.0, dt):
            h = solver.next_step(remaining, self._h_allowed)
            hs.append(h)
            ws.append(0.0 if h_prev == 0.0 else h / h_prev)
            h_prev = h
            remaining -= h
            self._h_allowed = min(h * s.growth, s.dt_max)
        if not hs:  # dt == 0 at the same current: re-solve the algebraic state
            hs, ws = [0.0], [0.0]
        n = len(hs)
        t_end = np.cumsum(hs)
        t_end[-1] = dt  # the sample ends the last step exactly
        emit = np.zeros(n, dtype=np.int32)
        emit[-1] = 1
        currents = np.full(n, I_dis)
        sample_t, sample_I = [dt], [I_dis]
        if changed:
            currents[0] = self._I_dis
            emit[0] = 1
            if n > 1:
                sample_t, sample_I = [0.0, dt], [I_dis, I_dis]
        plan = StepPlan.of(hs, ws, currents, np.full(n, ambient), t_end, emit)
        out = np.full((len(sample_t), 5), np.nan)
        dummy = np.zeros((len(sample_t), 1))
        lim = np.array([-np.inf, np.inf, np.inf])
        none = np.zeros(0, dtype=np.int32)
        y0, xp0 = self._y.copy(), self._xp.copy()

        def attempt() -> tuple[int, int]:
            samples = SamplePlan.of(sample_t, sample_I)
            done, code, _ = self._stepper.run(
                self._pivots,
                plan,
                samples,
                self._theta,
                none,
                self._y,
                self._xp,
                _EMPTY,
                _EMPTY,
                out,
                dummy,
                dummy,
                lim,
            )
            return done, code

        done, code = attempt()
        if code in (-2, -5):  # a pivot vanished: a new pivot order at this state, then retry from the start
            self._y, self._xp = y0, xp0
            if code == -5:
                zero = self._stepper.analyse_zero_at(self._y, np.array([0.0, 0.0, I_dis, ambient]), self._theta)
                self._pivots = self._pivots.replace(zero=zero)
            else:
                u = np.array([max(hs[-1], 1e-3), 0.0, I_dis, ambient])
                step = self._stepper.analyse_at(self._y, self._y[: len(xp0)], self._xp, u, self._theta)
                self._pivots = self._pivots.replace(step=step)
            done, code = attempt()
        if code < 0:
            raise RuntimeError(f"cell model: step did not converge at t = {self.t + sum(hs[:done]):.3f} s")
        self._I_dis = I_dis
        self._h_prev = h_prev if h_prev > 0 else self._h_prev
        V, T1, T2, smin, smax = out[-1]
        if not (smin > 0.0 and smax < 1.0):
            raise CellLimitError("cell model: a particle surface emptied or filled (the cell is beyond its limits)")
        return float(V), float(T1), float(T2)

    def step(self, current: float, dt: float, ambient: float) -> tuple[float, float]:
        """Apply ``current`` [A, positive = charge] for ``dt`` [s] at ``ambient`` [K]; return (V, T_surface).

        A step that does not converge is retried with a smaller first step, then as halves (each retried the same
        way, ``SPLIT_DEPTH`` levels). Where the solution ends inside the step with the voltage past the cell's limit
        in the current's direction (a particle surface emptying or filling: the voltage collapses, see
        :func:`battlab.model.dfn.edge_potential`), the cell stops where its voltage reaches V_min (V_max on charge),
        found by bisection, and holds there for the rest of the step and for later steps of the same current: a
        cycler's own limit catches a collapsing voltage at the cut-off, and the samples read it past the cut-off,
        where ``simulate`` ends. The next current starts from the held state, or, where the solver cannot follow it
        from there (the surface at its very edge), from the state where the held step began (at most one step's
        charge earlier). A step that fails otherwise raises ``RuntimeError`` and leaves the cell as it was
        before the step, so the next step (another current, a rest) starts from a valid state."""
        if dt < 0 or not np.isfinite(dt) or not np.isfinite(current):
            raise InputError(f"step: need finite current and dt ≥ 0, got {current} A, {dt} s")
        I_dis, dt, ambient = -float(current), float(dt), float(ambient)
        if self._held is not None and I_dis == self._held[0]:
            self.t += dt
            return self.voltage, self.T_surface
        held, self._held = self._held, None
        before = self._save()
        t0 = self.t

        def advance() -> None:
            self.voltage, self.T_core, self.T_surface = self._advance_split(I_dis, dt, ambient, SPLIT_DEPTH)

        try:
            advance()
        except RuntimeError:
            if held is None:
                self._restore(before)
                if not self._stop_at_limit(I_dis, dt, ambient):
                    self._restore(before)
                    raise
                self._held = (I_dis, before)
            else:  # leaving the limit: from the state where the held step began
                self._restore(held[1])
                self.t = t0
                try:
                    advance()
                except RuntimeError:
                    self._restore(before)
                    self._held = held
                    raise
        self.t = t0 + dt
        return self.voltage, self.T_surface

    def _stop_at_limit(self, I_dis: float, dt: float, ambient: float) -> bool:
        """From the state before a failed step: advance to where the voltage first reaches the cell's limit in the
        current's direction (bisection on the time into the step, each trial from the start state); False (the state
        undefined) when no trial that converges ends past the limit, i.e. the step failed short of it."""
        if I_dis == 0.0:
            return False
        limit = float(self.cell["V_min"]) if I_dis > 0 else float(self.cell["V_max"])

        def past(v: float) -> bool:
            return v <= limit if I_dis > 0 else v >= limit

        start = self._save()
        lo, hi, found = 0.0, dt, None
        for _ in range(LIMIT_BISECTIONS):
            mid = 0.5 * (lo + hi)
            self._restore(start)
            try:
                out = self._advance_split(I_dis, mid, ambient, SPLIT_DEPTH)
            except RuntimeError:
                hi = mid
                continue
            if past(out[0]):
                hi, found = mid, (self._save(), out)
            else:
                lo = mid
        if found is None:
            return False
        self._restore(found[0])
        self.voltage, self.T_core, self.T_surface = found[1]
        return True

    def _save(self) -> tuple:
        return (
            self._y.copy(),
            self._xp.copy(),
            self._I_dis,
            self._h_prev,
            self._h_allowed,
            self.t,
            self.voltage,
            self.T_core,
            self.T_surface,
        )

    def _restore(self, saved: tuple) -> None:
        y, xp, self._I_dis, self._h_prev, self._h_allowed, self.t, self.voltage, self.T_core, self.T_surface = saved
        self._y, self._xp = y.copy(), xp.copy()

    def _advance_split(self, I_dis: float, dt: float, ambient: float, depth: int) -> tuple[float, float, float]:
        """:meth:`_advance`; if that fails to converge, the two halves of ``dt`` in turn (``depth`` more levels)."""
        before = self._save()
        try:
            return self._advance(I_dis, dt, ambient)
        except CellLimitError:
            raise
        except RuntimeError:
            if depth == 0 or dt <= 0.0:
                raise
            self._restore(before)
        half = 0.5 * dt
        self._advance_split(I_dis, half, ambient, depth - 1)
        self.t += half
        return self._advance_split(I_dis, dt - half, ambient, depth - 1)
