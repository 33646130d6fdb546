"""Names and defaults shared by the BPX reader and writer (see :mod:`battlab.io.bpx`)."""

from __future__ import annotations

import math

import numpy as np

#: Prefix of battlab's own entries in the BPX "User-defined" section.
EXT = "battlab: "
#: Marker entry: present in every file battlab writes.
EXT_VERSION = EXT + "extension version"
#: Marker entry: 1 when the cell's stoichiometry window follows from n_Li and the voltage limits.
EXT_WINDOW = EXT + "stoichiometry window from n_Li"
#: Prefix of a model extension's parameter: "battlab: model extension KEY.NAME" (the extension is on when present)
EXT_MODEL = EXT + "model extension "
#: Functions PyBaMM's BPX reader can execute (its preamble imports exp, tanh, cosh only).
PYBAMM_FUNCTIONS = frozenset({"exp", "tanh", "cosh"})
#: Heat capacity fraction kept in the surface node, and core-surface relaxation time [s].
SURFACE_FRACTION = 1e-3
CORE_SURFACE_TAU = 1.0
T_MAX_DEFAULT = 333.15  # K, when a BPX file gives none
C_E0_DEFAULT = 1000.0  # mol/m3, PyBaMM's default initial electrolyte concentration
T_REF_DEFAULT = 298.15  # K
CP_NOMINAL = 1000.0  # J/(kg K), nominal split of rho*c_p on export
RHO_CP_DEFAULT = 2.0e6  # J/(m3 K) over the electrode stack, when a BPX file has no thermal data

CONSTANTS = {"pi": math.pi, "e": math.e}  # the named constants battlab expressions may use
STO_GRID = np.linspace(0.0, 1.0, 201)
CE_GRID = np.linspace(0.0, 6000.0, 241)
# keys whose value BPX cannot hold exactly: written as "battlab: <key>" and restored on reading
EXT_KEYS = (
    *("C1", "C2", "h12", "h2a", "T_max", "R_c", "R_f_n", "R_f_p", "E_R_f_n", "E_R_f_p", "n_Li", "k_n", "k_p"),
    *("dlnf", "dlnf_scale", "D_e", "D_e_scale", "kappa", "kappa_scale", "sigma_n", "sigma_p"),
    *("brugg_s_n", "brugg_s_p", "brugg_n", "brugg_s", "brugg_p", "B_n", "B_s", "B_p"),
    *("D_s_n", "D_s_p", "D_s_n_shape", "D_s_p_shape"),
)
