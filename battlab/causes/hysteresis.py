"""Open-circuit potential hysteresis: the electrodes' equilibrium potential depends on the direction the
stoichiometry last moved (lithiation and delithiation branches), relaxing onto the branch of the current's
direction as charge passes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence, Reason
from battlab.causes.evidence import rests_after_both_directions, reverses_direction
from battlab.causes.extension import Evaluation, Extension, Mesh
from battlab.constants import F
from battlab.specs import extension_parameter

KEY = "hysteresis"
_AXEN = (
    "one-state hysteresis: J. B. Axen, X. Chen, M. Fleischer, Energy Storage 4 (2022) e358; PyBaMM's "
    "'open-circuit potential': 'one-state hysteresis'"
)


@dataclass(frozen=True)
class Hysteresis(Extension):
    """One-state OCP hysteresis per electrode (Axen et al. 2022, as PyBaMM's "one-state hysteresis"): a state h ∈
    [−1, 1] per x cell, U = U_eq + M h in the reaction overpotential, and

        dh/dt = γ (a_s i − |a_s i| h) / (2 F c_max ε_s),

    so h → +1 on delithiation (a_s i > 0) and −1 on lithiation, at a rate γ per unit of stoichiometry passed; PyBaMM's
    form with equal lithiation and delithiation decay rates and its branches U_eq ± M. h starts at 0 (rest on the
    equilibrium curve). The heat's bulk OCP (B3) stays the equilibrium one."""

    key: ClassVar[str] = KEY

    def n_states(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def _h(self, c: Evaluation, e: str) -> ca.SX:
        h = c.y[c.sl[self.key]]
        n_n = c.nreg["n"]
        return h[:n_n] if e == "n" else h[n_n:]

    def open_circuit(self, c: Evaluation, e: str, U: ca.SX) -> ca.SX:
        return U + self.p(c, f"M_{e}") * self._h(c, e)

    def rates(self, c: Evaluation, x: ca.SX) -> ca.SX:
        out = []
        for e in ("n", "p"):
            h = self._h(c, e)
            i_vol = c.a_s[e] * c.i_int[e]
            scale = 2.0 * F * float(c.cell[f"c_max_{e}"]) * c.value(f"eps_s_{e}")
            out.append(self.p(c, f"gamma_{e}") * (i_vol - ca.fabs(i_vol) * h) / scale)
        return ca.vertcat(*out)


def _sweeps(experiments: Sequence[Any], i_rest: float) -> bool:
    """Its state moves only with the direction of the current: it shows in the relaxation after a charge and after
    a discharge, or while a reversal of the current sweeps it from one branch towards the other."""
    return rests_after_both_directions(experiments, i_rest) or reverses_direction(experiments, i_rest)


def _untestable(experiments: Sequence[Any], i_rest: float) -> Reason:
    """Why a diagnosis on these experiments cannot test it (None: it can)."""
    return None if _sweeps(experiments, i_rest) else "no rest after a charge and after a discharge, no reversal"


def _uninformed(name: str, experiments: Sequence[Any], i_rest: float) -> Reason:
    return (
        None
        if _sweeps(experiments, i_rest)
        else "no experiment rests after a charge and after a discharge or reverses the current with charge enough to "
        "move the state"
    )


CAUSE = Cause(
    key=KEY,
    title="OCP hysteresis",
    mechanism="open-circuit potentials that depend on the direction of the last lithiation (two branches)",
    informed_by=Evidence(
        "pulse",
        "charge and discharge pulses each followed by a rest (a change of direction, then relaxation onto the branch)",
    ),
    extension=Hysteresis,
    parameters=(
        extension_parameter(
            KEY, "M_n", "V", (0.0, 0.05), 0.0, "negative OCP hysteresis half-width", _AXEN, typical=0.012
        ),
        extension_parameter(
            KEY,
            "gamma_n",
            "1",
            (1.0, 200.0),
            50.0,
            "negative hysteresis decay rate per stoichiometry",
            _AXEN,
            shapes=True,
        ),
        extension_parameter(
            KEY, "M_p", "V", (0.0, 0.05), 0.0, "positive OCP hysteresis half-width", _AXEN, typical=0.005
        ),
        extension_parameter(
            KEY,
            "gamma_p",
            "1",
            (1.0, 200.0),
            50.0,
            "positive hysteresis decay rate per stoichiometry",
            _AXEN,
            shapes=True,
        ),
    ),
    slots=frozenset({"ocp_hysteresis_n", "ocp_hysteresis_p"}),
    uninformed=_uninformed,
    untestable=_untestable,
    example={"M_n": 0.01, "gamma_n": 30.0, "M_p": 0.005, "gamma_p": 80.0},
    validated_by="PyBaMM's 'one-state hysteresis' (benchmarks/bench_extensions.py)",
)
