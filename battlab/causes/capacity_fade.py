"""Capacity fade: lithium inventory and active material lost, both since the cell was parameterised (the base
values n_Li and ε_s±: a static loss) and during a test (the extension: an SEI-type side reaction that consumes
lithium, loss of active material at constant rates)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import casadi as ca
import numpy as np

from battlab.causes.cause import Cause, Evidence
from battlab.causes.extension import Evaluation, Extension, Mesh
from battlab.constants import R_GAS, F
from battlab.specs import extension_parameter

KEY = "capacity_fade"
_SEI = (
    "SEI growth, reaction limited: PyBaMM's 'SEI': 'reaction limited (asymmetric)' without film resistance (Marquis, "
    "DPhil thesis, Oxford 2020, eq. 5.92; Safari et al., J. Electrochem. Soc. 156 (2009) A145)"
)
_LAM = "loss of active material at a constant rate (cf. PyBaMM's 'loss of active material'; Reniers et al. 2019)"


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
        side reaction shrinks with the surface). Active material lost before the test (since the cell was
    parameterised): the fraction lost_e, a_s = (1 − lost_e) f_e · 3 ε_s/R_s: the electrode's capacity and surface
    shrink together, its particles' stoichiometry at a given voltage stays (PyBaMM's lower ε_s at the same
    stoichiometries)."""

    key: ClassVar[str] = KEY
    #: the surface potential difference [V] at which I_side is the side current
    U_ref: ClassVar[float] = 0.1

    def n_states(self, mesh: Mesh) -> int:
        return 2

    def initial_states(self, mesh: Mesh, soc0: float) -> np.ndarray:
        return np.ones(2)

    def side_current(self, c: Evaluation, e: str) -> ca.SX | None:
        if e != "n":
            return None
        n = c.nreg["n"]
        dphi = c.y[c.sl["phis_n"]] - c.phie[:n]
        tafel = ca.exp(-self.p(c, "alpha_side") * F / (R_GAS * c.T1) * (dphi - self.U_ref))
        f_n = c.y[c.sl[self.key]][0]
        return -self.p(c, "I_side") / (c.value("A") * c.L["n"]) * f_n * tafel

    def surface_area(self, c: Evaluation, e: str, a: ca.SX) -> ca.SX:
        f = c.y[c.sl[self.key]]
        return a * (1.0 - self.p(c, f"lost_{e}")) * (f[0] if e == "n" else f[1])

    def rates(self, c: Evaluation, x: ca.SX) -> ca.SX:
        return ca.vertcat(-self.p(c, "lam_n"), -self.p(c, "lam_p")) / 3600.0


CAUSE = Cause(
    key=KEY,
    title="capacity fade",
    mechanism="lithium inventory and active material lost since the cell was parameterised and during the test",
    informed_by=Evidence(
        "pulse",
        "a long test with rests at both ends and at several SOCs (a loss of capacity shows in the charge balance "
        "over hours, the side current's Tafel slope in how it changes with the negative electrode's potential)",
    ),
    base=("n_Li", "eps_s_n", "eps_s_p"),
    extension=CapacityFade,
    parameters=(
        extension_parameter(
            KEY,
            "I_side",
            "A",
            (0.0, 1.0),
            0.0,
            "lithium-consuming side-reaction current at 0.1 V",
            _SEI,
            typical=1.5e-3,
        ),
        extension_parameter(
            KEY, "alpha_side", "1", (0.0, 1.0), 0.0, "side reaction's cathodic transfer coefficient", _SEI, shapes=True
        ),
        extension_parameter(
            KEY, "lam_n", "1/h", (0.0, 0.01), 0.0, "negative active-material loss rate", _LAM, typical=1e-3
        ),
        extension_parameter(
            KEY, "lam_p", "1/h", (0.0, 0.01), 0.0, "positive active-material loss rate", _LAM, typical=1e-3
        ),
        extension_parameter(
            KEY, "lost_n", "1", (0.0, 0.3), 0.0, "negative active material lost before the test", _LAM, typical=0.03
        ),
        extension_parameter(
            KEY, "lost_p", "1", (0.0, 0.3), 0.0, "positive active material lost before the test", _LAM, typical=0.03
        ),
    ),
    slots=frozenset({"side_reaction_n", "active_material"}),
    example={"I_side": 0.005, "alpha_side": 0.5, "lam_n": 0.008, "lam_p": 0.004, "lost_n": 0.04, "lost_p": 0.06},
    validated_by="PyBaMM's reaction-limited SEI with current-driven loss of active material "
    "(benchmarks/bench_extensions.py)",
    separates={
        "equilibrium": "capacity checks before and after the tests (a loss during them lowers the capacity and moves "
        "the windows as the tests go on; shifted OCP curves leave both as they were)"
    },
)
