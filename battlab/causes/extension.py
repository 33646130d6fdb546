"""The hooks a cause's model extension uses to change the DFN–thermal model (paper Appendices A–B).

An extension is a frozen dataclass with one class per cause (declared in the cause's module, :mod:`battlab.causes`).
Its hooks are the model's extension points, called by :class:`battlab.model.dfn.DFN` in each physics block; each is
the identity by default. Its parameters (declared beside it in the cause) follow the 18 in θ̄, so the compiled
stepper gives their exact sensitivities like the 18.

Hooks read the evaluation state through :class:`Evaluation`, the part of the model's per-evaluation context they
may use (:class:`battlab.model.context.Context` satisfies it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import casadi as ca
import numpy as np


class Evaluation(Protocol):
    """One evaluation of the residual as the hooks see it. Model convention: current positive = discharge."""

    y: ca.SX  # the state vector
    sl: dict[str, slice]  # where each variable sits in y (an extension's states under its key)
    p: dict[str, ca.SX]  # physical values of the identified parameters (an extension's as ``KEY.NAME``)
    I_dis: ca.SX  # the current the cell carries [A]
    T1: ca.SX  # core temperature [K]
    T_ref: float  # reference temperature [K]
    ce: ca.SX  # electrolyte concentration per x cell [mol m⁻³]
    phie: ca.SX  # electrolyte potential per x cell [V]
    i_int: dict[str, ca.SX]  # interfacial current density per electrode cell [A m⁻²]
    a_s: dict[str, ca.SX]  # specific surface area per electrode [m⁻¹]
    surf: dict[str, ca.SX]  # surface stoichiometry per electrode cell
    U: dict[str, ca.SX]  # open-circuit potential per electrode cell in the overpotential [V]
    L: dict[str, float]  # region thicknesses [m]
    nreg: dict[str, int]  # cells per region
    cell: Any  # the cell (values by key, functions by ``cell.fn``)

    def value(self, key: str) -> Any:
        """A cell value as the equations must read it: the model's input for :data:`battlab.parameters.MODEL_INPUTS`
        (the compiled model serves every cell that differs only in them), the cell's number otherwise."""
        ...


class Mesh(Protocol):
    """What an extension's state counts depend on: cells per electrode."""

    n_n: int
    n_p: int


#: catalog key → the extension's parameters, registered by its cause's declaration
_PARAMETERS: dict[str, tuple[Any, ...]] = {}


def register_parameters(key: str, parameters: tuple[Any, ...]) -> None:
    """Bind an extension's parameters to its key (called by :class:`battlab.causes.cause.Cause`)."""
    _PARAMETERS[key] = parameters


@dataclass(frozen=True)
class Extension:
    """A submodel: states, equations and hooks. Subclasses are frozen dataclasses with a class variable ``key``
    (their cause's catalog key); instances are values (equal and hashing alike per class: a cache key)."""

    key: ClassVar[str]
    #: the extension only makes sense with the thermal model on (its parameters act through the temperature)
    requires_thermal: ClassVar[bool] = False

    @property
    def parameters(self) -> tuple[Any, ...]:
        """Its parameters (:class:`battlab.specs.ExtensionParameter`), as its cause declares them."""
        return _PARAMETERS[self.key]

    def p(self, c: Evaluation, name: str) -> ca.SX:
        """The physical value of one of this extension's parameters in this evaluation."""
        return c.p[f"{self.key}.{name}"]

    def n_states(self, mesh: Mesh) -> int:
        """Extra differential states (appended to x after the temperatures)."""
        return 0

    def initial_states(self, mesh: Mesh, soc0: float) -> np.ndarray:
        """Their values at rest."""
        return np.zeros(self.n_states(mesh))

    def n_algebraic(self, mesh: Mesh) -> int:
        """Extra algebraic states (appended to z after i⁺; 0 is their guess at rest)."""
        return 0

    def algebraic(self, c: Evaluation, z: ca.SX) -> ca.SX:
        """Residuals of this extension's algebraic states ``z`` (scaled to order 1)."""
        return ca.SX(0, 1)

    def capacitive_current(self, c: Evaluation, e: str) -> ca.SX | None:
        """A non-faradaic current per volume in electrode ``e`` [A m⁻³, + = out of the solid], or None: it takes
        part in charge conservation only."""
        return None

    def cell_current(self, c: Any, I_dis: ca.SX) -> ca.SX:
        """The current the cell carries [A, + = discharge], given the logged current ``I_dis`` (``c.p`` only: it is
        called before the rest of the evaluation exists)."""
        return I_dis

    def solid_diffusivity(self, c: Evaluation, e: str, shape: ca.SX | float, sto: ca.SX) -> ca.SX | float:
        """The concentration dependence of electrode ``e``'s solid diffusivity (A1): the factor on D_s at
        stoichiometry ``sto`` (a shell face or the surface), given the cell's own ``shape`` there."""
        return shape

    def open_circuit(self, c: Evaluation, e: str, U: ca.SX) -> ca.SX:
        """The open-circuit potential of electrode ``e`` in its reaction overpotential (A19) [V]."""
        return U

    def bulk_open_circuit(self, c: Evaluation, e: str, U: ca.SX, sto: ca.SX) -> ca.SX:
        """The open-circuit potential of electrode ``e`` at its mean bulk stoichiometry ``sto`` (in the heat, B3)."""
        return U

    def electrolyte_property(self, c: Evaluation, name: str, value: ca.SX) -> ca.SX:
        """An electrolyte property per x cell: ``D_e`` [m² s⁻¹], ``kappa`` [S m⁻¹] (both before the transport
        efficiency), ``dlnf`` (d ln f/d ln c_e)."""
        return value

    def voltage(self, c: Evaluation, V: ca.SX) -> ca.SX:
        """The terminal voltage (A21) [V]."""
        return V

    def rates(self, c: Evaluation, x: ca.SX) -> ca.SX:
        """Time derivatives of this extension's states ``x``."""
        return ca.SX(0, 1)

    def surface_area(self, c: Evaluation, e: str, a: ca.SX) -> ca.SX:
        """The specific surface area a_s of electrode ``e`` [m⁻¹] (3 ε_s/R_s in the base model)."""
        return a

    def side_current(self, c: Evaluation, e: str) -> ca.SX | None:
        """A side reaction's current per volume in electrode ``e`` [A m⁻³, + = anodic], or None: it takes part in
        charge conservation and the electrolyte's source, not in the particles' lithium."""
        return None

    def activation(self, c: Evaluation, key: str, E: ca.SX | float) -> ca.SX | float:
        """The activation energy ``key`` (``E_D_s_n``, ``E_k_p``, ``E_D_e``, ``E_kappa``, …) of B5 [J/mol]."""
        return E

    def heat(self, c: Evaluation, thermal: dict[str, ca.SX | float]) -> dict[str, ca.SX | float]:
        """The lumped thermal model's inputs (B1–B3): ``C1``, ``C2`` [J/K], ``h12``, ``h2a`` [W/K], ``dUdT`` [V/K]
        (the cell's entropic coefficient at the bulk stoichiometries)."""
        return thermal
