"""Solid diffusion: lithium transport inside the active particles (A1–A2): the diffusivities D_s± and the particle
radii R_s± (the voltage fixes only the diffusion times τ = R_s²/D_s, docs/decisions.md). The base model takes D_s
constant (or the cell's own shape); the extension lets it vary with the stoichiometry, as graphite's and layered
oxides' measured diffusivities do by one or two orders of magnitude over their range."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence
from battlab.causes.extension import Evaluation, Extension
from battlab.specs import extension_parameter

KEY = "solid_diffusion"
_DS = (
    "stoichiometry-dependent solid diffusivity, log-linear (cf. Ecker et al., J. Electrochem. Soc. 162 (2015) A1836; "
    "PyBaMM's particle diffusivity as a function of stoichiometry)"
)
#: the stoichiometry about which the log-slope is taken
STO_REF = 0.5


@dataclass(frozen=True)
class ConcentrationDependentDiffusivity(Extension):
    """D_s±(θ) = D_s± · f(θ) · exp(b± (θ − ½)), f the cell's own shape (1 without one): a log-linear dependence on
    the local stoichiometry, evaluated at each shell face and at the surface of A1–A2, so D_s± is the diffusivity
    at half lithiation and exp(b/2) the factor from there to full."""

    key: ClassVar[str] = KEY

    def solid_diffusivity(self, c: Evaluation, e: str, shape: ca.SX | float, sto: ca.SX) -> ca.SX | float:
        return shape * ca.exp(self.p(c, f"b_{e}") * (sto - STO_REF))


CAUSE = Cause(
    key=KEY,
    title="solid diffusion",
    mechanism="lithium diffusion inside the active particles",
    informed_by=Evidence(
        "pulse",
        "pulses with long rests at several SOCs (the relaxation's time constant is the diffusion time, and how it "
        "changes over the SOC window is the diffusivity's dependence on stoichiometry)",
    ),
    base=("D_s_n", "D_s_p", "R_s_n", "R_s_p"),
    extension=ConcentrationDependentDiffusivity,
    parameters=(
        extension_parameter(
            KEY, "b_n", "1", (-6.0, 6.0), 0.0, "log-slope of D_s- in the stoichiometry", _DS, typical=2.0
        ),
        extension_parameter(
            KEY, "b_p", "1", (-6.0, 6.0), 0.0, "log-slope of D_s+ in the stoichiometry", _DS, typical=2.0
        ),
    ),
    slots=frozenset({"solid_diffusivity_n", "solid_diffusivity_p"}),
    example={"b_n": 1.5, "b_p": -2.0},
    validated_by="PyBaMM's DFN with the same stoichiometry-dependent particle diffusivities "
    "(benchmarks/bench_extensions.py)",
)
