"""Equilibrium: the cell's open-circuit voltage as its electrodes' balance sets it (the stoichiometry windows from
the OCV test, eqs. 10–21) and corrections of the open-circuit potential curves: each electrode's curve shifted along
its stoichiometry and an offset of the cell's OCV."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence
from battlab.causes.extension import Evaluation, Extension
from battlab.specs import extension_parameter

KEY = "equilibrium"
_OCP = (
    "electrode balancing: OCP stoichiometry shifts and offset (Mohtat et al. 2019, as cited by PyBaMM's electrode SOH)"
)


@dataclass(frozen=True)
class Equilibrium(Extension):
    """Corrections of the open-circuit potentials: each electrode's curve shifted along its stoichiometry,
    U_e(θ + d_sto_e) (as a shift of its stoichiometry window would move it), and an offset dU [V] of the positive
    one (the cell's OCV; the two electrodes' offsets are indistinguishable in the voltage). It replaces the cell's
    curves (one evaluation instead of a difference of two), so it comes first of the causes that change an OCP."""

    key: ClassVar[str] = KEY

    def _corrected(self, c: Evaluation, e: str, sto: ca.SX) -> ca.SX:
        shifted = c.cell.fn(f"U_{e}", sto + self.p(c, f"d_sto_{e}"), backend="casadi")
        return shifted + self.p(c, "dU") if e == "p" else shifted

    def open_circuit(self, c: Evaluation, e: str, U: ca.SX) -> ca.SX:
        return self._corrected(c, e, c.surf[e])

    def bulk_open_circuit(self, c: Evaluation, e: str, U: ca.SX, sto: ca.SX) -> ca.SX:
        return self._corrected(c, e, sto)


CAUSE = Cause(
    key=KEY,
    title="equilibrium",
    mechanism="the electrodes' balance (stoichiometry windows) and their open-circuit potential curves",
    informed_by=Evidence("pulse", "long low-rate pulses (1000 s) over the SOC window with rests (the OCV curve)"),
    base=("sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100", "U_n", "U_p"),
    extension=Equilibrium,
    parameters=(
        extension_parameter(
            KEY, "d_sto_n", "1", (-0.05, 0.05), 0.0, "shift of the negative OCP in stoichiometry", _OCP, typical=0.008
        ),
        extension_parameter(
            KEY, "d_sto_p", "1", (-0.05, 0.05), 0.0, "shift of the positive OCP in stoichiometry", _OCP, typical=0.008
        ),
        extension_parameter(
            KEY, "dU", "V", (-0.02, 0.02), 0.0, "offset of the open-circuit voltage", _OCP, typical=0.003
        ),
    ),
    slots=frozenset({"ocp_curve_n", "ocp_curve_p"}),
    example={"d_sto_n": -0.005, "d_sto_p": 0.005, "dU": 0.003},
    validated_by="exact: the shifted curves are the cell's own (tests/battlab/model)",
    separates={
        "capacity_fade": "capacity checks before and after the tests (lithium lost during them shifts the windows "
        "as they go on and lowers the capacity; a shift of the OCP curves stays and leaves the capacity)"
    },
)
