"""BPX (Battery Parameter eXchange) import and export, following PyBaMM's BPX importer.

The mapping is that of ``pybamm/parameters/bpx.py`` (PyBaMM 26), so that a BPX cell simulated in battlab
and in PyBaMM is the same cell and starts from the same concentrations at the same SOC:

- electrolyte transport: BPX gives a transport efficiency B = ε^b per region; it becomes ``B_n``, ``B_s``,
  ``B_p`` (used instead of Bruggeman) and the equivalent exponent ``brugg_* = ln B / ln ε``, as PyBaMM does;
- electrode conductivities are effective values: ``sigma_*`` as given, ``brugg_s_* = 0``;
- area: ``A`` = electrode area × number of electrode pairs;
- active material: ε_s = a_s R_s / 3 from "Surface area per unit volume" (PyBaMM's "BET" line), so that
  a_s = 3 ε_s / R_s holds in the model;
- kinetics: BPX's j0 = F k_BPX √((c_e/c_e0)(c_s/c_max)(1 − c_s/c_max)) [mol m⁻² s⁻¹ → A m⁻²] equals
  battlab's (and PyBaMM's) j0 = k √(c_e c_s (c_max − c_s)) with k = k_BPX F / (c_max √c_e0), c_e0 the
  initial electrolyte concentration of the BPX ``State`` (1000 mol m⁻³ when absent, PyBaMM's default);
- thermodynamic factor 1 (``dlnf = 0``, ``dlnf_scale = 1``); no film or contact resistance (0);
- diffusivities given as functions of stoichiometry: ``D_s_*`` = D(θ = 0.5) and ``D_s_*_shape`` =
  D(θ)/D(0.5) (an expression or a scaled table); tables ``{"x", "y"}`` become :class:`Table`;
- SOC: ``sto_n_0``/``sto_n_100`` = negative minimum/maximum stoichiometry, ``sto_p_0``/``sto_p_100`` =
  positive maximum/minimum (PyBaMM's ``get_electrode_stoichiometries``); ``n_Li`` = H⁻θ⁻(0 %) + H⁺θ⁺(0 %);
- thermal: PyBaMM's lumped model is ρ c_p V dT/dt = Q − h A_ext (T − T_amb) with h from
  ``State.Thermal environment`` (0, adiabatic, when absent). battlab's two-state model (B1, B2) reproduces
  it with all heat capacity in the core and a stiff core-to-surface link: C1 + C2 = ρ c_p V with
  C2 = 10⁻³ ρ c_p V, h12 = ρ c_p V / (1 s) (core–surface relaxation C2/h12 = 1 ms; in steady cooling the
  core–surface difference is h2a/h12 of the rise over ambient), h2a = h A_ext. T_core is then PyBaMM's
  volume-averaged temperature (PyBaMM's lumped "surface temperature" is the ambient);
- ``T_max`` is not part of BPX: 333.15 K unless given, and the source says so.

Hysteresis: BPX cells with two OCP branches (BPX 1.x ``OCP (lithiation)``/``OCP (delithiation)`` or the
``User-defined`` "<Negative|Positive> electrode lithiation/delithiation OCP [V]" of the example file)
whose main OCP is a constant placeholder are read with the mean of the two branches (battlab does not
model hysteresis); a real main OCP is used as given, as PyBaMM does without a hysteresis option.

Export writes the current BPX schema of the installed ``bpx`` package (validated before writing) with the
same conventions in reverse (identified scale factors multiplied into D_e and κ, σ written as effective
σ ε_s^brugg_s, k converted back, the lumped-thermal equivalent ρ c_p V = C1 + C2 and h A_ext = h2a over a
nominal V = electrode-stack volume, c_p = 1000 J kg⁻¹ K⁻¹, A_ext = 6 V^(2/3)). Everything BPX cannot
hold (the two-state thermal values, T_max, R_c, R_f, the activity function, the scale factors, Bruggeman
exponents) is kept under ``User-defined`` as "battlab: <key>" entries, which :func:`read_bpx` restores,
so that battlab → BPX → battlab is exact; they take precedence over the standard fields, so remove them
when editing those fields of a battlab-written file by hand. Extra metadata (confidence intervals, a fit
report) goes under ``User-defined`` too, flattened to numbers; texts go to the header's Description.
"""

from battlab.cell import register_format
from battlab.io.bpx.common import EXT, EXT_VERSION, EXT_WINDOW
from battlab.io.bpx.read import read_bpx
from battlab.io.bpx.write import write_bpx

register_format("bpx", read_bpx, write_bpx)

__all__ = ["EXT", "EXT_VERSION", "EXT_WINDOW", "read_bpx", "write_bpx"]
