"""Contact resistance: electronic resistance in series with the cell (tabs, welds, current collectors) and in the
electrodes' solid phase. The base model holds the solid conductivities σ±; the extension adds a series resistance
with its own temperature coefficient.

A series resistance and the film resistances R_f± look alike on full-cell voltage: R_c drops I·R_c whatever the
reaction's distribution through the electrodes, a film's drop follows the local reaction current and departs from a
series resistance only where that distribution is far from uniform; the solid conductivities σ± act as one too. In
this model neither R_f nor σ has a temperature dependence of its own; on a real cell an SEI film's resistance is
thermally activated and a metal contact's barely changes, so pulses at two ambients tell them apart there."""

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
        "short pulses at two ambient temperatures (a real cell's film resistance is thermally activated, a series "
        "contact's barely changes)",
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
        "the charge transfer follows the kinetics' Arrhenius law, as a real cell's film resistance does)"
    },
)
