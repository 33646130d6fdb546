"""Double layer: charge stored at the particles' surface (a capacitance in parallel with the charge transfer),
seen in the first milliseconds to seconds after a current step."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence, Reason
from battlab.causes.extension import Evaluation, Extension, Mesh
from battlab.specs import extension_parameter

KEY = "double_layer"
_DL = "double layer in the differential surface form: PyBaMM 'surface form': 'differential' (Sulzer et al. 2021)"


@dataclass(frozen=True)
class DoubleLayer(Extension):
    """Double-layer capacitance at the particle surface (PyBaMM's "surface form": "differential"): per electrode
    cell a charge q [C m⁻²] (differential, dq/dt = i_dl) and its current i_dl [A m⁻²] (algebraic), with

        q = C_dl (φ_s − φ_e − U) − ε i_dl,   a_s (i + i_dl) in the charge balance,

    the faradaic i alone in the particles and the electrolyte's lithium. The capacitor is charged to the surface
    overpotential (against U rather than 0: q = 0 at rest at any SOC; U moves by < 1e-4 V/s at 1C, a current
    C_dl dU/dt far below i). ε = 1e-9 s (a 1e-9/C_dl Ω m² series resistance, < 1e-8 Ω m² for C_dl ≥ 0.1 F m⁻²)
    keeps the zero-length solves regular at C_dl = 0, where q = i_dl = 0 exactly: the base model."""

    key: ClassVar[str] = KEY
    EPS: ClassVar[float] = 1e-9  # [s]

    def n_states(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def n_algebraic(self, mesh: Mesh) -> int:
        return mesh.n_n + mesh.n_p

    def _split(self, c: Evaluation, v: ca.SX, e: str) -> ca.SX:
        n_n = c.nreg["n"]
        return v[:n_n] if e == "n" else v[n_n:]

    def rates(self, c: Evaluation, x: ca.SX) -> ca.SX:
        return c.y[c.sl[f"{self.key}.z"]]

    def capacitive_current(self, c: Evaluation, e: str) -> ca.SX | None:
        return c.a_s[e] * self._split(c, c.y[c.sl[f"{self.key}.z"]], e)

    def algebraic(self, c: Evaluation, z: ca.SX) -> ca.SX:
        q = c.y[c.sl[self.key]]
        off = {"n": 0, "p": c.nreg["n"] + c.nreg["s"]}
        out = []
        for e in ("n", "p"):
            phis = c.y[c.sl[f"phis_{e}"]]
            phie = c.phie[off[e] : off[e] + c.nreg[e]]
            i_dl = self._split(c, z, e)
            out.append(self._split(c, q, e) - self.p(c, f"C_dl_{e}") * (phis - phie - c.U[e]) + self.EPS * i_dl)
        return ca.vertcat(*out) / 1e-3  # [C m⁻²]: 1 mC m⁻² ~ 0.2 F m⁻² at 5 mV


def _untestable(experiments: Sequence[Any], i_rest: float) -> Reason:
    """Never score-tested: for any C_dl > 0 the right limit at a current step holds the charge-transfer
    overpotential (the capacitor), at 0 it jumps; its effect at 1 s samples can be mV, but only a fit can weigh
    it."""
    return "not score-tested: its voltage is not differentiable at its off value C_dl = 0"


CAUSE = Cause(
    key=KEY,
    title="double layer",
    mechanism="charge stored at the particle surface in parallel with the charge transfer",
    informed_by=Evidence(
        "pulse", "1 s and 3 s bipolar pulses sampled at 10 Hz or faster, fitted with the double layer on"
    ),
    extension=DoubleLayer,
    parameters=(
        extension_parameter(
            KEY, "C_dl_n", "F/m2", (0.0, 2.0), 0.0, "negative double-layer capacitance", _DL, typical=0.3
        ),
        extension_parameter(
            KEY, "C_dl_p", "F/m2", (0.0, 2.0), 0.0, "positive double-layer capacitance", _DL, typical=0.3
        ),
    ),
    slots=frozenset({"double_layer"}),
    untestable=_untestable,
    differentiable_at_off=False,
    example={"C_dl_n": 0.2, "C_dl_p": 0.3},
    validated_by="PyBaMM's 'surface form': 'differential' (benchmarks/bench_extensions.py)",
)
