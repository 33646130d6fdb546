"""The constraint screen of the input library, filled in by the model (paper: T_surface ≤ 50 °C; voltage window).

:class:`ModelScreen` is the ``screen(profile) -> (ok, reason)`` hook of :meth:`protocols.Library.build` and
:meth:`protocols.Library.screen`: it simulates the profile (no sensitivities) from its start SOC and flags it when
the run leaves the cell's voltage window, exceeds the surface-temperature limit, or drives a particle surface to
empty or full. :func:`constraint_flags` is the same test on an existing :class:`battlab.Result`; the sensitivity
sweep (:mod:`battlab.design.sweep`) uses it so that the screen and the sweep agree by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.simulation import Result, simulate
from protocols.profile import Profile

T_SURFACE_MAX_K = 323.15
"""Library constraint: surface temperature ≤ 50 °C [K]."""


@dataclass(frozen=True)
class Limits:
    """Screen limits: surface temperature [K] and voltage window [V] (None: the cell's V_min/V_max)."""

    T_surface_max: float = T_SURFACE_MAX_K
    V_min: float | None = None
    V_max: float | None = None

    def window(self, cell: Cell) -> tuple[float, float]:
        """(V_min, V_max) [V]: the given ones or the cell's."""
        lo = float(cell["V_min"]) if self.V_min is None else self.V_min
        hi = float(cell["V_max"]) if self.V_max is None else self.V_max
        return lo, hi


def is_solver_failure(ended_by: str | None) -> bool:
    """True when a run stopped because the solver failed (not because a physical limit was reached)."""
    return ended_by is not None and ended_by.startswith("solver")


def constraint_flags(result: Result, limits: Limits, window: tuple[float, float]) -> list[str]:
    """Reasons why ``result`` violates the screen (empty list: feasible).

    ``ended_by`` (the run stopped at a voltage, temperature or stoichiometry limit) is one reason; the surface
    temperature and the voltage are also checked on the samples, so a limit tighter than the cell's is honoured.
    """
    out: list[str] = []
    if result.ended_by is not None and not is_solver_failure(result.ended_by):
        out.append(f"stopped early: {result.ended_by} at t = {float(result.t[-1]) if result.t.size else 0.0:g} s")
    if result.T_surface.size:
        tmax = float(np.max(result.T_surface))
        if tmax > limits.T_surface_max:
            out.append(f"T_surface {tmax - 273.15:.2f} degC > {limits.T_surface_max - 273.15:g} degC")
    if result.voltage.size:
        vmin, vmax = float(np.min(result.voltage)), float(np.max(result.voltage))
        if vmin < window[0]:
            out.append(f"V {vmin:.4f} < {window[0]:g} V")
        if vmax > window[1]:
            out.append(f"V {vmax:.4f} > {window[1]:g} V")
    return out


@dataclass
class ModelScreen:
    """Picklable ``screen(profile) -> (ok, reason)`` for :meth:`protocols.Library.screen` (runs the model).

    Build it with :meth:`for_cell`; the cell travels as its TOML dict (cells hold mapping proxies, which do not
    pickle), so the screen can be handed to ``ProcessPoolExecutor.map`` or a Dask client.
    """

    cell_dict: dict[str, Any]
    limits: Limits = field(default_factory=Limits)
    ambient: float = 298.15
    _cell: Cell | None = field(default=None, init=False, repr=False, compare=False)

    @classmethod
    def for_cell(cls, cell: Cell, limits: Limits | None = None, ambient: float = 298.15) -> ModelScreen:
        return cls(cell.to_toml_dict(), limits or Limits(), ambient)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_cell"] = None
        return state

    @property
    def cell(self) -> Cell:
        if self._cell is None:
            self._cell = Cell._from_toml_dict(self.cell_dict, str(self.cell_dict.get("name", "cell")))
        return self._cell

    def __call__(self, profile: Profile) -> tuple[bool, str | None]:
        window = self.limits.window(self.cell)
        try:
            res = simulate(self.cell, profile, ambient=self.ambient, v_limits=window)
        except Exception as exc:  # a model failure is a flag with its reason, never a crash of the screen
            return False, f"simulation failed: {type(exc).__name__}: {exc}"
        if is_solver_failure(res.ended_by):
            return False, f"simulation failed: {res.ended_by}"
        flags = constraint_flags(res, self.limits, window)
        return (not flags), ("; ".join(flags) or None)
