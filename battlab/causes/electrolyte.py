"""Electrolyte transport: how lithium ions move and carry current in the electrolyte (diffusivity, conductivity,
transference number, thermodynamic factor, the volume fractions through the transport efficiency, the initial
concentration). The base model scales the cell's functions as a whole; the extension adds their concentration
dependence beyond the cell's functions."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence
from battlab.causes.extension import Evaluation, Extension
from battlab.specs import extension_parameter

KEY = "electrolyte"
_VR = (
    "concentration dependence of LiPF6 electrolytes: L. O. Valoen, J. N. Reimers, J. Electrochem. Soc. 152 (2005) A882"
)
#: concentration the slopes are taken about [mol m⁻³]
C_E_REF = 1000.0


@dataclass(frozen=True)
class Electrolyte(Extension):
    """Concentration dependence of the electrolyte's properties beyond the cell's functions: D_e, κ and
    d ln f/d ln c_e each multiplied by 1 + s (c_e/c_ref − 1), c_ref = 1000 mol m⁻³ (slopes De_slope, kappa_slope,
    dlnf_slope). The base model's D_e_scale, kappa_scale, dlnf_scale and t_plus already scale them as a whole;
    a concentration-dependent t⁺ (which adds a ∇t⁺ · i_e term) is not included."""

    key: ClassVar[str] = KEY
    _names: ClassVar[dict[str, str]] = {"D_e": "De_slope", "kappa": "kappa_slope", "dlnf": "dlnf_slope"}

    def electrolyte_property(self, c: Evaluation, name: str, value: ca.SX) -> ca.SX:
        return value * (1.0 + self.p(c, self._names[name]) * (c.ce / C_E_REF - 1.0))


CAUSE = Cause(
    key=KEY,
    title="electrolyte transport",
    mechanism="ion transport in the electrolyte: diffusivity, conductivity, transference number, activity",
    informed_by=Evidence("pulse", "long high-rate pulses (300-1000 s at 2C or more: large electrolyte gradients)"),
    base=("D_e_scale", "kappa_scale", "t_plus", "dlnf_scale", "eps_e_n", "eps_e_s", "eps_e_p", "c_e0"),
    extension=Electrolyte,
    parameters=(
        extension_parameter(
            KEY, "De_slope", "1", (-1.0, 1.0), 0.0, "relative slope of D_e in c_e/1000 mol m-3", _VR, typical=0.4
        ),
        extension_parameter(
            KEY, "kappa_slope", "1", (-1.0, 1.0), 0.0, "relative slope of kappa in c_e/1000 mol m-3", _VR, typical=0.4
        ),
        extension_parameter(
            KEY, "dlnf_slope", "1", (-1.0, 1.0), 0.0, "relative slope of dlnf in c_e/1000 mol m-3", _VR, typical=0.4
        ),
    ),
    slots=frozenset({"electrolyte_properties"}),
    example={"De_slope": 0.3, "kappa_slope": -0.4, "dlnf_slope": 0.5},
    validated_by="central differences of its exact sensitivities (tests/battlab/model); PyBaMM has no such option",
)
