"""What one evaluation of the DFN's residual shares between its physics blocks and the extensions' hooks: the state's
variables, the physical parameters, the geometry and what each block computes (:meth:`battlab.model.dfn.DFN.equations`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from battlab.cell import Cell


@dataclass
class Context:
    """One evaluation of the residual: the state's variables, the physical parameters and what the blocks of
    :meth:`DFN.equations` compute, in the order they run (solid diffusion, electrolyte, charge, kinetics, voltage,
    thermal). Model convention: current positive = discharge."""

    y: ca.SX
    I_dis: ca.SX  # the current the cell carries [A] (the logged one unless an extension says otherwise)
    T_amb: ca.SX  # ambient temperature [K]
    p: dict[str, ca.SX]  # physical values of the identified parameters
    sl: dict[str, slice]
    i_app: ca.SX  # I/A [A m⁻²]
    T1: ca.SX  # core temperature [K]
    T2: ca.SX  # surface temperature [K]
    ce: ca.SX  # electrolyte concentration per x cell [mol m⁻³]
    phie: ca.SX  # electrolyte potential per x cell [V]
    i_int: dict[str, ca.SX]  # interfacial current density per electrode cell [A m⁻²]
    L: dict[str, float]  # region thicknesses [m]
    nreg: dict[str, int]  # cells per region
    dx: np.ndarray  # cell widths [m]
    eps_x: ca.SX  # electrolyte volume fraction per x cell
    tort_x: ca.SX  # transport efficiency per x cell
    T_ref: float = 298.15  # reference temperature [K]
    cell: Cell | None = None
    #: the cell values the compiled model takes as inputs (:data:`battlab.parameters.MODEL_INPUTS`): symbols there,
    #: the cell's numbers in a model built for one cell
    inputs: dict[str, ca.SX | float] = field(default_factory=dict)
    i_ref: ca.SX | float = 1.0  # 1C current density [A m⁻²]: the scale of the algebraic rows
    zero: ca.SX = field(default_factory=lambda: ca.SX(1, 1))
    a_s: dict[str, ca.SX] = field(default_factory=dict)  # specific surface area [m⁻¹]
    f_s: dict[str, ca.SX] = field(default_factory=dict)  # dθ/dt of the shells
    surf: dict[str, ca.SX] = field(default_factory=dict)  # surface stoichiometry per x cell
    bulk: dict[str, ca.SX] = field(default_factory=dict)  # mean stoichiometry per x cell
    side: dict[str, ca.SX] = field(default_factory=dict)  # side-reaction current per volume [A m⁻³] (+ = anodic)
    capacitive: dict[str, ca.SX] = field(default_factory=dict)  # double-layer current per volume [A m⁻³]
    U: dict[str, ca.SX] = field(default_factory=dict)  # OCP per electrode cell in the overpotential [V]
    src: ca.SX | None = None  # a_s i per x cell [A m⁻³]
    dce: ca.SX | None = None
    g_e: ca.SX | None = None
    g_s: dict[str, ca.SX] = field(default_factory=dict)
    phis_L: ca.SX | None = None  # φ_s at the positive collector [V]
    g_bv: dict[str, ca.SX] = field(default_factory=dict)
    U_bulk: ca.SX | float = 0.0  # U⁺ − U⁻ at the electrodes' mean bulk stoichiometries [V]
    dUdT_bulk: ca.SX | float = 0.0  # its temperature derivative [V K⁻¹]
    V: ca.SX | None = None  # terminal voltage [V]
    Q: ca.SX | None = None  # heat [W]
    dT1: ca.SX | None = None
    dT2: ca.SX | None = None

    def value(self, key: str) -> ca.SX | float:
        """A cell value the equations read: the model's input where it is one, else the cell's number."""
        if key in self.inputs:
            return self.inputs[key]
        assert self.cell is not None
        return float(self.cell[key])


@dataclass
class PartialContext:
    """What a hook may read before the context exists (the parameters: :meth:`Extension.cell_current`)."""

    p: dict[str, ca.SX]


def a_s_i(c: Context, e: str) -> ca.SX:
    """a_s i of electrode e [A m⁻³]: the volumetric reaction current (with the side reactions' when there are)."""
    out = c.a_s[e] * c.i_int[e]
    if e in c.side:
        out = out + c.side[e]
    return out
