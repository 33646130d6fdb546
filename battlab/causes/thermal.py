"""Thermal behaviour: how the cell heats and cools (heat capacities, heat transfer to the ambient, the entropic
term) and how its transport and kinetics follow temperature (the Arrhenius activation energies, B5).

The base model holds the cell's values; the extension makes them identifiable: changes of the six activation
energies, factors on the heat transfer and the heat capacities, an offset of the entropic coefficient."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence, Reason
from battlab.causes.evidence import ambient_text, one_ambient
from battlab.causes.extension import Evaluation, Extension
from battlab.specs import extension_parameter

KEY = "thermal"
_ZHANG = "Arrhenius activation energies as in Q. Zhang et al., J. Power Sources 270 (2014) 367 (the cell's own values)"
_LIN = "two-state lumped thermal model: X. Lin et al., J. Power Sources 257 (2014) 1 (heat capacities, heat transfer)"
#: the activation energies of B5 the extension changes
ACTIVATED = ("D_s_n", "D_s_p", "k_n", "k_p", "D_e", "kappa")


@dataclass(frozen=True)
class Thermal(Extension):
    """The temperature dependence as identifiable parameters: changes of the six activation energies of B5
    (dE_D_s_n, dE_D_s_p, dE_k_n, dE_k_p, dE_D_e, dE_kappa [J/mol] added to the cell's), factors on the surface-to-
    ambient heat transfer (h2a_scale; 0 is adiabatic) and on both heat capacities (C_scale), and an offset of the
    cell's entropic coefficient (dUdT_offset [V/K], in the reversible heat of B3). It acts through the temperature:
    an isothermal simulation with it on is a contradiction (an error)."""

    key: ClassVar[str] = KEY
    requires_thermal: ClassVar[bool] = True

    def activation(self, c: Evaluation, key: str, E: ca.SX | float) -> ca.SX | float:
        """The six energies of :data:`ACTIVATED` moved by their changes; the films' (E_R_f±) as the cell has them."""
        return E + self.p(c, "d" + key) if key.removeprefix("E_") in ACTIVATED else E

    def heat(self, c: Evaluation, thermal: dict[str, ca.SX | float]) -> dict[str, ca.SX | float]:
        k = self.p(c, "C_scale")
        return {
            **thermal,
            "C1": k * thermal["C1"],
            "C2": k * thermal["C2"],
            "h2a": self.p(c, "h2a_scale") * thermal["h2a"],
            "dUdT": thermal["dUdT"] + self.p(c, "dUdT_offset"),
        }


def _uninformed(name: str, experiments: Sequence[Any], i_rest: float) -> Reason:
    """Activation energies act only through a change of temperature: every experiment at one ambient cannot
    inform them (the self-heating of a few kelvin is what the base scales absorb)."""
    return ambient_text(experiments) if name.startswith("dE_") and one_ambient(experiments) else None


def _untestable(experiments: Sequence[Any], i_rest: float) -> Reason:
    """At one ambient only the logged surface temperature shows the heat balance (the activation energies act only
    through a change of temperature): without it nothing of the cause can be tested."""
    logged = any(getattr(e, "has_temperature", False) for e in experiments)
    if one_ambient(experiments) and not logged:
        return (
            "one ambient temperature and no surface temperature logged: activation energies are seen only through "
            "a change of temperature, the heat balance only in the temperature"
        )
    return None


CAUSE = Cause(
    key=KEY,
    title="thermal behaviour",
    mechanism="heat capacities, heat transfer, the entropic heat and the activation energies of transport and kinetics",
    informed_by=Evidence(
        "drive",
        "the same profile at two ambient temperatures (activation energies act only through a change of temperature)",
    ),
    base=("C1", "C2", "h12", "h2a", "E_D_s_n", "E_D_s_p", "E_k_n", "E_k_p", "E_D_e", "E_kappa", "E_R_f_n", "E_R_f_p"),
    extension=Thermal,
    parameters=(
        *(
            extension_parameter(
                KEY,
                f"dE_{k}",
                "J/mol",
                (-30000.0, 30000.0),
                0.0,
                f"change of the activation energy E_{k}",
                _ZHANG,
                typical=10e3,
            )
            for k in ACTIVATED
        ),
        extension_parameter(
            KEY,
            "h2a_scale",
            "1",
            (0.0, 4.0),
            1.0,
            "factor on the surface-to-ambient heat transfer h2a",
            _LIN,
            typical=0.4,
        ),
        extension_parameter(
            KEY, "C_scale", "1", (0.25, 4.0), 1.0, "factor on the heat capacities C1 and C2", _LIN, typical=0.2
        ),
        extension_parameter(
            KEY,
            "dUdT_offset",
            "V/K",
            (-3e-4, 3e-4),
            0.0,
            "offset of the cell's entropic coefficient",
            _LIN,
            typical=5e-5,
        ),
    ),
    slots=frozenset({"activation_energies", "heat_balance"}),
    uninformed=_uninformed,
    untestable=_untestable,
    example={"dE_D_s_n": 5000.0, "dE_k_p": -8000.0, "dE_kappa": 3000.0, "h2a_scale": 1.5, "dUdT_offset": 1e-4},
    validated_by="PyBaMM's lumped thermal model with changed activation energies (benchmarks/bench_extensions.py)",
)
