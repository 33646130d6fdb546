"""Model extensions: submodels of the compiled DFN–thermal model, chosen by a typed options value.

An extension is a class (a frozen dataclass, one per catalog key). It declares its named parameters (in
:data:`battlab.parameters.EXTENSIONS`: unit, the "off" value with which the model is the base model exactly,
bounds, citation), its extra differential states (if any), and its contributions to the physics blocks of
:class:`~battlab.model.dfn.DFN` through the hooks below, each the identity by default. Its parameters are appended
to θ̄ (after the 18), so the compiled stepper gives exact sensitivities w.r.t. them like the 18.

:class:`ModelOptions` is the option set: the thermal option and the extensions, in catalog order. It is part of
the compiled stepper's cache key (the generated source differs per option set).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import casadi as ca
import numpy as np

from battlab import parameters
from battlab.cell import R_GAS, F
from protocols.errors import InputError

if TYPE_CHECKING:
    from battlab.cell import Cell
    from battlab.model.context import Context
    from battlab.model.mesh import Mesh


@dataclass(frozen=True)
class Extension:
    """A submodel. Hooks take the evaluation :class:`~battlab.model.context.Context` (``c.p`` holds the physical
    values of every parameter, an extension's as ``KEY.NAME``) and return the changed quantity."""

    key: ClassVar[str]
    #: the extension only makes sense with the thermal model on (its parameters act through the temperature)
    requires_thermal: ClassVar[bool] = False

    @property
    def parameters(self) -> tuple[parameters.ExtensionParameter, ...]:
        return parameters.EXTENSIONS[self.key]

    def p(self, c: Context, name: str) -> ca.SX:
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

    def algebraic(self, c: Context, z: ca.SX) -> ca.SX:
        """Residuals of this extension's algebraic states ``z`` (scaled to order 1)."""
        return ca.SX(0, 1)

    def capacitive_current(self, c: Context, e: str) -> ca.SX | None:
        """A non-faradaic current per volume in electrode ``e`` [A m⁻³, + = out of the solid], or None: it takes
        part in charge conservation only."""
        return None

    def cell_current(self, c: Context, I_dis: ca.SX) -> ca.SX:
        """The current the cell carries [A, + = discharge], given the logged current ``I_dis``."""
        return I_dis

    def open_circuit(self, c: Context, e: str, U: ca.SX) -> ca.SX:
        """The open-circuit potential of electrode ``e`` in its reaction overpotential (A19) [V]."""
        return U

    def bulk_open_circuit(self, c: Context, e: str, U: ca.SX, sto: ca.SX) -> ca.SX:
        """The open-circuit potential of electrode ``e`` at its mean bulk stoichiometry ``sto`` (in the heat, B3)."""
        return U

    def electrolyte_property(self, c: Context, name: str, value: ca.SX) -> ca.SX:
        """An electrolyte property per x cell: ``D_e`` [m² s⁻¹], ``kappa`` [S m⁻¹] (both before the transport
        efficiency), ``dlnf`` (d ln f/d ln c_e)."""
        return value

    def voltage(self, c: Context, V: ca.SX) -> ca.SX:
        """The terminal voltage (A21) [V]."""
        return V

    def rates(self, c: Context, x: ca.SX) -> ca.SX:
        """Time derivatives of this extension's states ``x``."""
        return ca.SX(0, 1)

    def surface_area(self, c: Context, e: str, a: ca.SX) -> ca.SX:
        """The specific surface area a_s of electrode ``e`` [m⁻¹] (3 ε_s/R_s in the base model)."""
        return a

    def side_current(self, c: Context, e: str) -> ca.SX | None:
        """A side reaction's current per volume in electrode ``e`` [A m⁻³, + = anodic], or None: it takes part in
        charge conservation and the electrolyte's source, not in the particles' lithium."""
        return None

    def activation(self, c: Context, key: str, E: ca.SX | float) -> ca.SX | float:
        """The activation energy ``key`` (``E_D_s_n``, ``E_k_p``, ``E_D_e``, ``E_kappa``, …) of B5 [J/mol]."""
        return E

    def heat(self, c: Context, thermal: dict[str, ca.SX | float]) -> dict[str, ca.SX | float]:
        """The lumped thermal model's inputs (B1–B3): ``C1``, ``C2`` [J/K], ``h12``, ``h2a`` [W/K], ``dUdT`` [V/K]
        (the cell's entropic coefficient at the bulk stoichiometries)."""
        return thermal


@dataclass(frozen=True)
class ContactResistance(Extension):
    """A series resistance R_c + dRc_dT (T₁ − T_ref) [Ω] on top of the cell's fixed R_c: V −= R I. Its Joule heat
    R I² enters B3 through V (Bernardi's Q = I (U − V) − I T ∂U/∂T), as in PyBaMM's "contact resistance" option."""

    key: ClassVar[str] = "contact_resistance"

    def voltage(self, c: Context, V: ca.SX) -> ca.SX:
        R = self.p(c, "R_c") + self.p(c, "dRc_dT") * (c.T1 - c.T_ref)
        return V - R * c.I_dis


@dataclass(frozen=True)
class CurrentSensor(Extension):
    """The logged current is a sensor's: I_log = (1 + gain) I_cell + offset (public sign, + = charge). The cell
    carries I_cell = (I_log − offset)/(1 + gain); the model's input stays the logged current."""

    key: ClassVar[str] = "current_sensor"

    def cell_current(self, c: Context, I_dis: ca.SX) -> ca.SX:
        # model sign (+ = discharge): I_dis,log = (1 + gain) I_dis,cell − offset
        return (I_dis + self.p(c, "offset")) / (1.0 + self.p(c, "gain"))


@dataclass(frozen=True)
class Hysteresis(Extension):
    """One-state OCP hysteresis per electrode (Axen et al. 2022, as PyBaMM's "one-state hysteresis"): a state h ∈
    [−1, 1] per x cell, U = U_eq + M h in the reaction overpotential, and

        dh/dt = γ (a_s i − |a_s i| h) / (2 F c_max ε_s),

    so h → +1 on delithiation (a_s i > 0) and −1 on lithiation, at a rate γ per unit of stoichiometry passed; PyBaMM's
    form with equal lithiation and delithiation decay rates and its branches U_eq ± M. h starts at 0 (rest on the
    equilibrium curve). The heat's bulk OCP (B3) stays the equilibrium one."""

    key: ClassVar[str] = "hysteresis"

    def n_states(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def _h(self, c: Context, e: str) -> ca.SX:
        h = c.y[c.sl[self.key]]
        n_n = c.nreg["n"]
        return h[:n_n] if e == "n" else h[n_n:]

    def open_circuit(self, c: Context, e: str, U: ca.SX) -> ca.SX:
        return U + self.p(c, f"M_{e}") * self._h(c, e)

    def rates(self, c: Context, x: ca.SX) -> ca.SX:
        from battlab.cell import F

        out = []
        for e in ("n", "p"):
            h = self._h(c, e)
            i_vol = c.a_s[e] * c.i_int[e]
            scale = 2.0 * F * float(c.cell[f"c_max_{e}"]) * float(c.cell[f"eps_s_{e}"])
            out.append(self.p(c, f"gamma_{e}") * (i_vol - ca.fabs(i_vol) * h) / scale)
        return ca.vertcat(*out)


@dataclass(frozen=True)
class Thermal(Extension):
    """The temperature dependence as identifiable parameters: changes of the six activation energies of B5
    (dE_D_s_n, dE_D_s_p, dE_k_n, dE_k_p, dE_D_e, dE_kappa [J/mol] added to the cell's), factors on the surface-to-
    ambient heat transfer (h2a_scale) and on both heat capacities (C_scale), and an offset of the cell's entropic
    coefficient (dUdT_offset [V/K], in the reversible heat of B3). It acts through the temperature: an isothermal
    simulation with it on is a contradiction (an error)."""

    key: ClassVar[str] = "thermal"
    requires_thermal: ClassVar[bool] = True

    def activation(self, c: Context, key: str, E: ca.SX | float) -> ca.SX | float:
        return E + self.p(c, "d" + key)

    def heat(self, c: Context, thermal: dict[str, ca.SX | float]) -> dict[str, ca.SX | float]:
        k = self.p(c, "C_scale")
        return {
            **thermal,
            "C1": k * thermal["C1"],
            "C2": k * thermal["C2"],
            "h2a": self.p(c, "h2a_scale") * thermal["h2a"],
            "dUdT": thermal["dUdT"] + self.p(c, "dUdT_offset"),
        }


@dataclass(frozen=True)
class CapacityFade(Extension):
    """Ageing during a test. A lithium-consuming side reaction in the negative electrode (SEI growth, reaction
    limited, Tafel kinetics): per volume a_s j_side [A m⁻³], cathodic, with

        j_side = −I_side / (a_s⁰ A L⁻) · exp(−α_side F / (R T) (φ_s − φ_e − U_ref)),   U_ref = 0.1 V,

    so I_side [A] is the total side current while the surface potential difference φ_s − φ_e is at U_ref (graphite
    near half lithiated) and α_side = 0 makes it a constant rate. It is PyBaMM's reaction-limited SEI
    (``"SEI": "reaction limited (asymmetric)"``, no film resistance, growth activation energy 0) with
    j0_sei = I_side / (a_s⁰ A L⁻) · exp(−α_side F / (R T_ref) (U_sei − U_ref)). The side reaction takes Li⁺ from
    the electrolyte and its electrons through the solid: in the charge balance (A9–A16) the particles' intercalation
    current falls short of the cell's by the side current, so cyclable lithium is lost at ∫ a_s j_side dV / F (and
    the cell self-discharges at rest, a mixed potential). Loss of active material at a constant rate per electrode:
    a state f_e (the fraction left, from 1) with df_e/dt = −lam_e/3600 and a_s = f_e · 3 ε_s/R_s (PyBaMM's
    "current-driven" loss of active material at a constant rate: the lost material takes its lithium with it, the
    side reaction shrinks with the surface)."""

    key: ClassVar[str] = "capacity_fade"
    #: the surface potential difference [V] at which I_side is the side current
    U_ref: ClassVar[float] = 0.1

    def n_states(self, mesh: Mesh) -> int:
        return 2

    def initial_states(self, mesh: Mesh, soc0: float) -> np.ndarray:
        return np.ones(2)

    def side_current(self, c: Context, e: str) -> ca.SX | None:
        if e != "n":
            return None
        n = c.nreg["n"]
        dphi = c.y[c.sl["phis_n"]] - c.phie[:n]
        tafel = ca.exp(-self.p(c, "alpha_side") * F / (R_GAS * c.T1) * (dphi - self.U_ref))
        f_n = c.y[c.sl[self.key]][0]
        return -self.p(c, "I_side") / (float(c.cell["A"]) * c.L["n"]) * f_n * tafel

    def surface_area(self, c: Context, e: str, a: ca.SX) -> ca.SX:
        f = c.y[c.sl[self.key]]
        return a * (f[0] if e == "n" else f[1])

    def rates(self, c: Context, x: ca.SX) -> ca.SX:
        return ca.vertcat(-self.p(c, "lam_n"), -self.p(c, "lam_p")) / 3600.0


@dataclass(frozen=True)
class DoubleLayer(Extension):
    """Double-layer capacitance at the particle surface (PyBaMM's "surface form": "differential"): per electrode
    cell a charge q [C m⁻²] (differential, dq/dt = i_dl) and its current i_dl [A m⁻²] (algebraic), with

        q = C_dl (φ_s − φ_e − U) − ε i_dl,   a_s (i + i_dl) in the charge balance,

    the faradaic i alone in the particles and the electrolyte's lithium. The capacitor is charged to the surface
    overpotential (against U rather than 0: q = 0 at rest at any SOC; U moves by < 1e-4 V/s at 1C, a current
    C_dl dU/dt far below i). ε = 1e-9 s (a 1e-9/C_dl Ω m² series resistance, < 1e-8 Ω m² for C_dl ≥ 0.1 F m⁻²)
    keeps the zero-length solves regular at C_dl = 0, where q = i_dl = 0 exactly: the base model."""

    key: ClassVar[str] = "double_layer"
    EPS: ClassVar[float] = 1e-9  # [s]

    def n_states(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def n_algebraic(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def _split(self, c: Context, v: ca.SX, e: str) -> ca.SX:
        n_n = c.nreg["n"]
        return v[:n_n] if e == "n" else v[n_n:]

    def rates(self, c: Context, x: ca.SX) -> ca.SX:
        return c.y[c.sl[f"{self.key}.z"]]

    def capacitive_current(self, c: Context, e: str) -> ca.SX | None:
        return c.a_s[e] * self._split(c, c.y[c.sl[f"{self.key}.z"]], e)

    def algebraic(self, c: Context, z: ca.SX) -> ca.SX:
        q = c.y[c.sl[self.key]]
        off = {"n": 0, "p": c.nreg["n"] + c.nreg["s"]}
        out = []
        for e in ("n", "p"):
            phis = c.y[c.sl[f"phis_{e}"]]
            phie = c.phie[off[e] : off[e] + c.nreg[e]]
            i_dl = self._split(c, z, e)
            out.append(self._split(c, q, e) - self.p(c, f"C_dl_{e}") * (phis - phie - c.U[e]) + self.EPS * i_dl)
        return ca.vertcat(*out) / 1e-3  # [C m⁻²]: 1 mC m⁻² ~ 0.2 F m⁻² at 5 mV


#: concentration the electrolyte extension's slopes are taken about [mol m⁻³]
C_E_REF = 1000.0


@dataclass(frozen=True)
class Electrolyte(Extension):
    """Concentration dependence of the electrolyte's properties beyond the cell's functions: D_e, κ and
    d ln f/d ln c_e each multiplied by 1 + s (c_e/c_ref − 1), c_ref = 1000 mol m⁻³ (slopes De_slope, kappa_slope,
    dlnf_slope). The base model's D_e_scale, kappa_scale, dlnf_scale and t_plus already scale them as a whole;
    a concentration-dependent t⁺ (which adds a ∇t⁺ · i_e term) is not included."""

    key: ClassVar[str] = "electrolyte"
    _names: ClassVar[dict[str, str]] = {"D_e": "De_slope", "kappa": "kappa_slope", "dlnf": "dlnf_slope"}

    def electrolyte_property(self, c: Context, name: str, value: ca.SX) -> ca.SX:
        return value * (1.0 + self.p(c, self._names[name]) * (c.ce / C_E_REF - 1.0))


@dataclass(frozen=True)
class Equilibrium(Extension):
    """Corrections of the open-circuit potentials: each electrode's curve shifted along its stoichiometry,
    U_e(θ + d_sto_e) (as a shift of its stoichiometry window would move it), and an offset dU [V] of the positive
    one (the cell's OCV; the two electrodes' offsets are indistinguishable in the voltage)."""

    key: ClassVar[str] = "equilibrium"

    def _corrected(self, c: Context, e: str, U: ca.SX, sto: ca.SX) -> ca.SX:
        # replaces the cell's U (it comes first of the OCP hooks in catalog order, so U is the cell's own): one
        # evaluation of the curve instead of a difference of two
        shifted = c.cell.fn(f"U_{e}", sto + self.p(c, f"d_sto_{e}"), backend="casadi")
        return shifted + self.p(c, "dU") if e == "p" else shifted

    def open_circuit(self, c: Context, e: str, U: ca.SX) -> ca.SX:
        return self._corrected(c, e, U, c.surf[e])

    def bulk_open_circuit(self, c: Context, e: str, U: ca.SX, sto: ca.SX) -> ca.SX:
        return self._corrected(c, e, U, sto)


#: catalog key → extension class, in catalog order (the order of θ̄ after the 18)
CATALOG: dict[str, type[Extension]] = {
    cls.key: cls
    for cls in (
        ContactResistance,
        CurrentSensor,
        Thermal,
        Equilibrium,
        Hysteresis,
        DoubleLayer,
        CapacityFade,
        Electrolyte,
    )
}
assert tuple(CATALOG) == tuple(parameters.EXTENSIONS), "the catalog and the parameter registry must agree"


@dataclass(frozen=True)
class ModelOptions:
    """The option set of one compiled model: the thermal option and the extensions that are on (catalog order).

    Immutable and hashable: a cache key. Contradictory options are one :class:`InputError`."""

    isothermal: bool = False
    extensions: tuple[Extension, ...] = ()

    def __post_init__(self) -> None:
        keys = [e.key for e in self.extensions]
        if len(set(keys)) != len(keys):
            raise InputError(f"model options: an extension is given twice ({keys})")
        order = list(CATALOG)
        assert order.index("equilibrium") < order.index("hysteresis"), "equilibrium replaces U: it must come first"
        object.__setattr__(self, "extensions", tuple(sorted(self.extensions, key=lambda e: order.index(e.key))))
        if self.isothermal:
            bad = [e.key for e in self.extensions if e.requires_thermal]
            if bad:
                raise InputError(
                    f"extension {bad[0]!r} acts through the temperature: it cannot be on in an isothermal simulation"
                )

    @classmethod
    def of(cls, cell: Cell, isothermal: bool = False) -> ModelOptions:
        """The options a cell's extensions ask for."""
        return cls(bool(isothermal), tuple(CATALOG[k]() for k in cell.extensions))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """θ̄'s names: the 18, then every extension's ``KEY.NAME``."""
        return parameters.NAMES + tuple(p.qualified for e in self.extensions for p in e.parameters)
