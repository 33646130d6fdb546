"""Cell physics for the virtual tester, injected through :class:`CellPhysics`.

battlab wires its DFN–thermal model in through this protocol; :class:`EquivalentCircuitCell` is a
**stand-in** (an OCV curve, a series resistance, one RC pair and a lumped thermal mass) so that the drivers
and their tests need nothing from battlab. Hidden effects (the diagnosis work) wrap a physics object in
another one with the same protocol (:class:`PhysicsWrapper`, e.g. :class:`ContactResistance`).

Current positive = charge; temperatures in K; time in s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


@dataclass(frozen=True)
class CellLimits:
    """The cell's safe operating window (SI units; current magnitudes)."""

    v_min_V: float = 2.5
    v_max_V: float = 4.2
    i_charge_max_A: float = 13.5
    i_discharge_max_A: float = 13.5
    T_max_K: float = 273.15 + 60.0


@runtime_checkable
class CellPhysics(Protocol):
    """What the virtual cycler needs from a cell model."""

    @property
    def limits(self) -> CellLimits:
        """The cell's limits."""
        ...

    @property
    def voltage(self) -> float:
        """Terminal voltage / V at the end of the last step (the OCV after :meth:`reset`)."""
        ...

    def reset(self, soc0: float, T_amb_K: float) -> None:
        """Start at rest at state of charge ``soc0`` (0–1), cell at ``T_amb_K``."""
        ...

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        """Apply ``current_A`` (positive = charge) for ``dt_s`` s with the air at ``ambient_K``.

        Returns ``(voltage_V, T_surface_K)`` at the end of the step. May raise (e.g. a solver failure), leaving
        the cell as it was before the step; the virtual cycler then turns its output off and reports it, and
        clearing its protection lets the next run go on from that state.
        """
        ...


def open_circuit_current(physics: CellPhysics) -> float:
    """The current [A] to step ``physics`` at while no current flows through the cell (the cycler's output off): its
    optional ``open_circuit_current_A`` (a model whose input is a logged current reads a sensor's offset on an open
    circuit, :class:`battlab.lab.virtual.DFNPhysics`), else 0."""
    return float(getattr(physics, "open_circuit_current_A", 0.0))


#: A hidden effect: wraps one physics object into another (applied in order by the virtual lab).
Effect = Callable[[CellPhysics], CellPhysics]


def apply_effects(physics: CellPhysics, effects: Sequence[Effect]) -> CellPhysics:
    for effect in effects:
        physics = effect(physics)
    return physics


@dataclass
class EquivalentCircuitParameters:
    """Stand-in parameters of a 2.7 Ah NCA/graphite 18650 (rough, for testing the drivers only)."""

    capacity_Ah: float = 2.7
    R0_ohm: float = 0.030  # series resistance at T_ref
    R1_ohm: float = 0.015  # RC pair
    tau1_s: float = 30.0
    E_R_K: float = 3000.0  # Arrhenius activation temperature of the resistances
    T_ref_K: float = 298.15
    heat_capacity_J_K: float = 46.0  # 46 g × ~1000 J kg⁻¹ K⁻¹
    hA_W_K: float = 0.042  # h ≈ 10 W m⁻² K⁻¹ × 0.0042 m²


def nca_ocv(soc: float) -> float:
    """A smooth, monotone NCA/graphite-like OCV / V (2.65 V at 0, 4.15 V at 1); not a fitted curve."""
    return 2.95 + 1.15 * soc - 0.30 * math.exp(-25.0 * soc) + 0.05 * math.exp(-20.0 * (1.0 - soc))


class EquivalentCircuitCell:
    """Stand-in :class:`CellPhysics`: OCV(soc) + R0·I + RC pair, lumped thermal mass to ambient.

    Integration is exact for the RC pair and the thermal node with the heat of the step's start state.
    """

    def __init__(
        self,
        params: EquivalentCircuitParameters | None = None,
        limits: CellLimits | None = None,
        ocv: Callable[[float], float] = nca_ocv,
    ) -> None:
        self.params = params or EquivalentCircuitParameters()
        self._limits = limits or CellLimits(
            i_charge_max_A=5 * self.params.capacity_Ah, i_discharge_max_A=5 * self.params.capacity_Ah
        )
        self.ocv = ocv
        self.soc = 0.5
        self.v_rc = 0.0
        self.T_K = self.params.T_ref_K
        self._voltage = ocv(self.soc)

    @property
    def limits(self) -> CellLimits:
        return self._limits

    @property
    def voltage(self) -> float:
        return self._voltage

    def reset(self, soc0: float, T_amb_K: float) -> None:
        if not 0.0 <= soc0 <= 1.0:
            raise ValueError(f"soc0 must be in [0, 1], got {soc0}")
        self.soc, self.v_rc, self.T_K = float(soc0), 0.0, float(T_amb_K)
        self._voltage = self.ocv(self.soc)

    def _arrhenius(self) -> float:
        p = self.params
        return math.exp(p.E_R_K * (1.0 / self.T_K - 1.0 / p.T_ref_K))

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        if dt_s < 0:
            raise ValueError(f"dt_s must be >= 0, got {dt_s}")
        p = self.params
        f = self._arrhenius()
        r0, r1 = p.R0_ohm * f, p.R1_ohm * f
        heat_W = current_A * current_A * r0 + current_A * self.v_rc
        decay = math.exp(-dt_s / p.tau1_s)
        self.v_rc = current_A * r1 + (self.v_rc - current_A * r1) * decay
        self.soc = min(1.05, max(-0.05, self.soc + current_A * dt_s / (3600.0 * p.capacity_Ah)))
        T_inf = ambient_K + heat_W / p.hA_W_K
        self.T_K = T_inf + (self.T_K - T_inf) * math.exp(-dt_s * p.hA_W_K / p.heat_capacity_J_K)
        self._voltage = self.ocv(self.soc) + current_A * r0 + self.v_rc
        return self._voltage, self.T_K


class PhysicsWrapper:
    """Base of hidden effects: delegates everything to ``inner``; override :meth:`step`."""

    def __init__(self, inner: CellPhysics) -> None:
        self.inner = inner

    @property
    def limits(self) -> CellLimits:
        return self.inner.limits

    @property
    def voltage(self) -> float:
        return self.inner.voltage

    @property
    def open_circuit_current_A(self) -> float:
        return open_circuit_current(self.inner)

    def reset(self, soc0: float, T_amb_K: float) -> None:
        self.inner.reset(soc0, T_amb_K)

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        return self.inner.step(current_A, dt_s, ambient_K)


class ContactResistance(PhysicsWrapper):
    """A hidden effect: an extra series resistance (e.g. a poor tab contact) the model does not know."""

    def __init__(self, inner: CellPhysics, resistance_ohm: float) -> None:
        super().__init__(inner)
        self.resistance_ohm = float(resistance_ohm)
        self._last_current = 0.0

    @property
    def voltage(self) -> float:
        return self.inner.voltage + self._last_current * self.resistance_ohm

    def reset(self, soc0: float, T_amb_K: float) -> None:
        self._last_current = 0.0
        super().reset(soc0, T_amb_K)

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        v, T = self.inner.step(current_A, dt_s, ambient_K)
        self._last_current = current_A
        return v + current_A * self.resistance_ohm, T
