"""Contact resistance: electronic resistance in series with the cell (tabs, welds, current collectors) and in the
electrodes' solid phase. The base model holds the solid conductivities σ±; the extension adds a series resistance
with its own temperature coefficient.

A series resistance and the film resistances R_f± differ only in their temperature dependence (R_f's follows the
kinetics' Arrhenius law, R_c's a linear coefficient): at one ambient the data cannot tell them apart."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence, Reason
from battlab.causes.evidence import ambient_text, one_ambient
from battlab.causes.extension import Evaluation, Extension
from battlab.specs import extension_parameter

KEY = "contact_resistance"
_GUO = "M. Guo, G. Sikha, R. E. White, J. Electrochem. Soc. 158 (2011) A122 (contact resistance in a P2D model)"
_PYBAMM = "PyBaMM lithium_ion options: 'contact resistance' (Sulzer et al., J. Open Res. Softw. 9 (2021) 14)"


@dataclass(frozen=True)
class ContactResistance(Extension):
    """A series resistance R_c + dRc_dT (T₁ − T_ref) [Ω] on top of the cell's fixed R_c: V −= R I (A21). Its Joule
    heat R I² enters B3 through V (Bernardi's Q = I (U − V) − I T ∂U/∂T), as in PyBaMM's "contact resistance"
    option."""

    key: ClassVar[str] = KEY

    def voltage(self, c: Evaluation, V: ca.SX) -> ca.SX:
        R = self.p(c, "R_c") + self.p(c, "dRc_dT") * (c.T1 - c.T_ref)
        return V - R * c.I_dis


def _uninformed(name: str, experiments: Sequence[Any], i_rest: float) -> Reason:
    """Its temperature coefficient shows only through a change of temperature (a metal contact's is about 0.4 %/K:
    the self-heating of a test at one ambient moves it by a few 0.1 %)."""
    return ambient_text(experiments) if name == "dRc_dT" and one_ambient(experiments) else None


CAUSE = Cause(
    key=KEY,
    title="contact resistance",
    mechanism="electronic resistance in series with the cell and in the electrodes' solid phase",
    informed_by=Evidence(
        "pulse",
        "short pulses at two ambient temperatures (a series resistance and the film resistance R_f differ only in "
        "their temperature dependence)",
    ),
    base=("sigma_n", "sigma_p", "R_c"),
    extension=ContactResistance,
    parameters=(
        extension_parameter(
            KEY, "R_c", "Ohm", (0.0, 0.02), 0.0, "series contact resistance at T_ref", _GUO, typical=0.005
        ),
        extension_parameter(KEY, "dRc_dT", "Ohm/K", (-3e-5, 3e-5), 0.0, "its temperature coefficient", _PYBAMM),
    ),
    slots=frozenset({"series_resistance"}),
    uninformed=_uninformed,
    example={"R_c": 0.004, "dRc_dT": 2e-5},
    validated_by="PyBaMM's 'contact resistance' option on a BPX cell (benchmarks/bench_extensions.py)",
    separates={
        "kinetics": "short pulses at two ambient temperatures (a series resistance barely changes with temperature, "
        "the film resistance and the charge transfer follow the kinetics' Arrhenius law)"
    },
)
