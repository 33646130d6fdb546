"""The DFN–thermal model (paper Appendices A and B) as a finite-volume DAE in CasADi.

Equations, with one global x from the negative current collector (x = 0) to the positive one (x = L), current
positive = discharge inside the model (the paper's and PyBaMM's convention; :mod:`battlab.simulate` converts),
j as the interfacial current density i = F j_n [A m⁻²] (positive = lithium leaving the solid):

- solid diffusion (A1–A2) in the normalised radius ξ = r/R_s: ∂θ/∂t = D/(R_s² ξ²) ∂ξ(ξ² ∂ξ θ),
  −(D c_max/R_s) ∂ξθ(1) = i/F, so R_s is a parameter (sensitivities w.r.t. it exist);
- electrolyte diffusion (A3–A8): ε_e ∂c_e/∂t = ∂x(D_e^eff ∂x c_e) + (1 − t⁺) a_s i/F, zero flux at the
  collectors, continuity of c_e and flux at the region interfaces (two-point fluxes with harmonic means);
- charge in the solid (A9–A10) and the electrolyte (A11–A16): ∂x i_e = a_s i, i_s + i_e = I/A,
  i_e = −κ^eff ∂xφ_e + κ^eff (2RT₁/F)(1 − t⁺)(1 + dlnf) ∂x ln c_e; φ_s = 0 at x = 0 (the reference, A12's
  role), no solid current at the separator, I/A at x = L;
- Butler–Volmer (A17–A20), α_a = α_c = 0.5: i = 2 i₀ sinh(F η/(2RT₁)),
  i₀ = k √(c_ss (c_max − c_ss) c_e), η = φ_s − φ_e − U(c_ss) − R_f i;
- voltage (A21): V = φ_s(L) − φ_s(0) − R_c I;
- thermal (B1–B4) with Bernardi's heat Q = I (U_bulk − V) − I T₁ ∂U_bulk/∂T (docs/decisions.md) and the
  Arrhenius law ψ = ψ_ref exp[(E/R)(1/T_ref − 1/T₁)] (B5 corrected) for D_s, D_e, κ, k and the films'
  conductance 1/R_f;
- effective properties: ψ^eff = ψ ε^b (Bruggeman) or ψ B (a BPX transport efficiency); a_s = 3 ε_s/R_s.

The 18 identified parameters enter as normalised values θ̄ (eq. 1), symbolic inputs of every function, so the
same compiled functions serve any parameter values and give derivatives w.r.t. θ̄ directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.constants import R_GAS, F
from battlab.model.context import Context, PartialContext, a_s_i
from battlab.model.extensions import ModelOptions
from battlab.model.mesh import Mesh

C_SCALE = 1000.0  #: electrolyte concentration scale [mol m⁻³]: the unknown is c_e / C_SCALE


#: width [-] of the stoichiometry edges over which an electrode's potential carries the ideal-solution divergence
#: (:func:`edge_potential`)
EDGE_WIDTH = 2e-3
#: where the term goes over into its tangent, in units of the width (:func:`edge_potential`)
EDGE_JOIN = 0.05


def edge_potential(sto: ca.SX, T: ca.SX, width: float = EDGE_WIDTH) -> ca.SX:
    """The ideal-solution term at an insertion electrode's stoichiometry limits [V], added to its OCP at the particle
    surface (A19's U): (RT/F)·[ln(1 − e^(−(1−θ)/w)) − ln(1 − e^(−θ/w))], w = ``width``.

    Every insertion compound's potential carries the configurational term −(RT/F)·ln(θ/(1−θ)), which diverges where
    the host empties or fills; fitted OCP curves lose it (the NMC811 fit of the nca18650 cells is flat at 3.49 V up to
    θ = 1). Without it a surface driven to its limit has no solution above the cut-off: the voltage falls at tens of
    mV/s and the solver stops mid-step ("singular Jacobian", "Newton did not converge", "surface stoichiometry reached
    0"). With it the voltage runs on through the cut-off. Confined to the edges: 1.2 μV at 10 w from a limit, 0.17 mV
    at 5 w, 1.3 mV at 3 w (the nca18650 cells' negative electrode at 0 % SOC, θ⁻ = 0.0056 = 2.8 w: 1.6 mV, where
    dU⁻/dθ = 92 V: a shift of 2e-5 in θ). Past a limit (a Newton iterate, or the extrapolated surface value of a
    particle under a large flux) it goes on as its tangent from ``EDGE_JOIN`` w, finite and steep. Tried: undefined
    (NaN) past a limit ended more slow discharges cleanly but left no right limit for a 3-4C step at -20 °C (its
    continuation in the current met the NaN); a softplus continuation gave a Jacobian the solver took for singular.
    """
    u0 = EDGE_JOIN * width
    g0 = float(np.log(-np.expm1(-EDGE_JOIN)))  # ln(1 − e^(−u/w)) at u0 and its slope there
    s0 = float(np.exp(-EDGE_JOIN) / -np.expm1(-EDGE_JOIN)) / width

    def log_gap(u: ca.SX) -> ca.SX:  # fmax: if_else evaluates both branches, the log must not see u <= 0
        return ca.if_else(u > u0, ca.log(-ca.expm1(-ca.fmax(u, u0) / width)), g0 + s0 * (u - u0))

    return (R_GAS * T / F) * (log_gap(1.0 - sto) - log_gap(sto))


@dataclass(frozen=True)
class Layout:
    """Where each variable sits in the unknown vector y = [x (differential) | z (algebraic)]."""

    mesh: Mesh
    extra: tuple[tuple[str, int], ...] = ()  #: extensions' differential states (key, count), after T₂
    extra_z: tuple[tuple[str, int], ...] = ()  #: extensions' algebraic states (key, count), after i⁺

    @cached_property
    def n_sn(self) -> int:
        return self.mesh.n_n * self.mesh.n_r

    @cached_property
    def n_sp(self) -> int:
        return self.mesh.n_p * self.mesh.n_r

    @cached_property
    def nx(self) -> int:
        """Differential states: θ⁻ shells, θ⁺ shells, c_e, T₁ − T_ref, T₂ − T_ref, the extensions' states."""
        return self.n_sn + self.n_sp + self.mesh.n_x + 2 + sum(n for _, n in self.extra)

    @cached_property
    def nz(self) -> int:
        """Algebraic states: φ_s⁻, φ_s⁺, φ_e, i⁻, i⁺, the extensions' algebraic states."""
        m = self.mesh
        return 2 * (m.n_n + m.n_p) + m.n_x + sum(n for _, n in self.extra_z)

    @cached_property
    def ny(self) -> int:
        return self.nx + self.nz

    def slices(self) -> dict[str, slice]:
        return dict(self._slices)

    @cached_property
    def _slices(self) -> dict[str, slice]:
        m = self.mesh
        out: dict[str, slice] = {}
        pos = 0
        for name, n in (
            ("sn", self.n_sn),
            ("sp", self.n_sp),
            ("ce", m.n_x),
            ("T1", 1),
            ("T2", 1),
            *self.extra,
            ("phis_n", m.n_n),
            ("phis_p", m.n_p),
            ("phie", m.n_x),
            ("i_n", m.n_n),
            ("i_p", m.n_p),
            *((f"{k}.z", n) for k, n in self.extra_z),
        ):
            out[name] = slice(pos, pos + n)
            pos += n
        return out


def _arrhenius(E: float, T_ref: float, T: ca.SX) -> ca.SX:
    """exp[(E/R)(1/T_ref − 1/T)]: rises with T for E > 0 (B5 with the sign corrected)."""
    return ca.exp(E / R_GAS * (1.0 / T_ref - 1.0 / T))


def _shape(cell: Cell, key: str, x: ca.SX) -> ca.SX | float:
    f = cell.get(key)
    return 1.0 if f is None else cell.fn(key, x, backend="casadi")


class DFN:
    """Builds the symbolic residual of one cell on one mesh."""

    def __init__(self, cell: Cell, mesh: Mesh | None = None, *, isothermal: bool = False) -> None:
        mesh = mesh or Mesh()
        self.cell = cell
        self.mesh = mesh
        self.options = ModelOptions.of(cell, isothermal)  # the extensions come with the cell
        extra = tuple((e.key, e.n_states(mesh)) for e in self.options.extensions if e.n_states(mesh))
        extra_z = tuple((e.key, e.n_algebraic(mesh)) for e in self.options.extensions if e.n_algebraic(mesh))
        self.layout = Layout(mesh, extra, extra_z)
        self.isothermal = isothermal
        self.T_ref = float(cell["T_ref"])
        self.xi_f = mesh.radial_faces()
        self.xi_c = 0.5 * (self.xi_f[1:] + self.xi_f[:-1])
        self.vol = (self.xi_f[1:] ** 3 - self.xi_f[:-1] ** 3) / 3.0  # shell volumes / R³

    @cached_property
    def stoichiometry_window(self) -> tuple[float, float, float, float]:
        """The cell's (θ⁻ at 0 %, θ⁻ at 100 %, θ⁺ at 0 %, θ⁺ at 100 %), solved once per model: it depends on values
        the model is built for (lithium inventory, capacities, potentials), never on θ̄."""
        return self.cell.stoichiometry_window()

    @cached_property
    def _ocp(self) -> ca.Function:
        s_n, s_p = ca.SX.sym("s_n"), ca.SX.sym("s_p")
        U = [self.cell.fn("U_n", s_n, backend="casadi"), self.cell.fn("U_p", s_p, backend="casadi")]
        return ca.Function("ocp", [s_n, s_p], U)

    def ocp(self, sto_n: float, sto_p: float) -> tuple[float, float]:
        """(U⁻(θ⁻), U⁺(θ⁺)) at T_ref [V], compiled once per model (a start state's guess needs them per run)."""
        un, up = self._ocp(sto_n, sto_p)
        return float(un), float(up)

    # --- parameters -----------------------------------------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of θ̄'s entries: the 18, then the extensions' ``KEY.NAME``."""
        return self.options.parameter_names

    @property
    def n_theta(self) -> int:
        return len(self.options.parameter_names)

    def input_values(self) -> np.ndarray:
        """This cell's values of :data:`battlab.parameters.MODEL_INPUTS`, in order: the compiled model's input after
        θ̄."""
        return np.array([float(self.cell[k]) for k in parameters.MODEL_INPUTS])

    def physical(self, theta_bar: ca.SX) -> dict[str, ca.SX]:
        """θ from θ̄ (eq. 1) as symbolic expressions, keyed by :attr:`parameter_names`."""
        out = {}
        for k, name in enumerate(self.options.parameter_names[len(parameters.DYNAMIC) :], len(parameters.DYNAMIC)):
            spec_e = parameters.EXTENSION_SPECS[name]
            out[name] = spec_e.lower + theta_bar[k] * (spec_e.upper - spec_e.lower)
        for k, spec in enumerate(parameters.DYNAMIC):
            tb = theta_bar[k]
            if spec.scale is parameters.Scale.LOG:
                out[spec.name] = ca.exp(np.log(spec.lower) + tb * (np.log(spec.upper) - np.log(spec.lower)))
            else:
                out[spec.name] = spec.lower + tb * (spec.upper - spec.lower)
        return out

    # --- the model ------------------------------------------------------------------------------------
    def equations(
        self, y: ca.SX, I_dis: ca.SX, T_amb: ca.SX, theta_bar: ca.SX, inputs: ca.SX | None = None
    ) -> dict[str, ca.SX]:
        """f (time derivatives of x), g (algebraic residuals, scaled), V and diagnostics at state y.

        I_dis: cell current [A], positive = discharge. T_amb: ambient temperature [K]. ``inputs``: symbols for the
        values of :data:`battlab.parameters.MODEL_INPUTS` (None: the cell's numbers). The physics blocks below
        (as PyBaMM's submodels) each read the shared quantities of :class:`Context` and add their own.
        """
        c = self.context(y, I_dis, T_amb, theta_bar, inputs)
        self.solid_diffusion(c)
        for ext in self.options.extensions:
            for e in ("n", "p"):
                side = ext.side_current(c, e)
                if side is not None:
                    c.side[e] = c.side[e] + side if e in c.side else side
        self.electrolyte(c)
        self.charge(c)
        self.kinetics(c)
        self.voltage(c)
        self.thermal(c)
        rates = [e.rates(c, c.y[c.sl[e.key]]) for e in self.options.extensions if e.key in c.sl]
        f = ca.vertcat(c.f_s["n"], c.f_s["p"], c.dce, c.dT1, c.dT2, *rates)
        alg = [e.algebraic(c, c.y[c.sl[f"{e.key}.z"]]) for e in self.options.extensions if f"{e.key}.z" in c.sl]
        g = ca.vertcat(c.g_s["n"], c.g_s["p"], c.g_e, c.g_bv["n"], c.g_bv["p"], *alg)
        sto_surf = ca.vertcat(c.surf["n"], c.surf["p"])
        return {
            "f": f,
            "g": g,
            "V": c.V,
            "T1": c.T1,
            "T2": c.T2,
            "Q": c.Q,
            "surf_n": c.surf["n"],
            "surf_p": c.surf["p"],
            "sto_surf": sto_surf,
            "ce": c.ce,
        }

    def context(self, y: ca.SX, I_dis: ca.SX, T_amb: ca.SX, theta_bar: ca.SX, inputs: ca.SX | None = None) -> Context:
        """The state split into its variables, the parameters and the geometry every block shares."""
        cell, m, sl = self.cell, self.mesh, self.layout.slices()
        p = self.physical(theta_bar)
        keys = parameters.MODEL_INPUTS
        given = {k: (inputs[j] if inputs is not None else float(cell[k])) for j, k in enumerate(keys)}
        L = {"n": float(cell["L_n"]), "s": float(cell["L_s"]), "p": float(cell["L_p"])}
        nreg = {"n": m.n_n, "s": m.n_s, "p": m.n_p}
        dx = np.concatenate([np.full(nreg[r], L[r] / nreg[r]) for r in ("n", "s", "p")])
        eps = {"n": p["eps_e_n"], "s": p["eps_e_s"], "p": p["eps_e_p"]}

        def transport(r: str) -> ca.SX:
            key = f"B_{r}"
            if key in cell.values:
                return float(cell[key])
            return eps[r] ** float(cell[f"brugg_{r}"])

        I_cell = I_dis
        for ext in self.options.extensions:
            I_cell = ext.cell_current(PartialContext(p), I_cell)
        return Context(
            y=y,
            I_dis=I_cell,
            T_amb=T_amb,
            p=p,
            sl=sl,
            i_app=I_cell / given["A"],
            T1=self.T_ref + y[sl["T1"]],
            T2=self.T_ref + y[sl["T2"]],
            ce=y[sl["ce"]] * C_SCALE,
            phie=y[sl["phie"]],
            i_int={e: y[sl[f"i_{e}"]] for e in ("n", "p")},
            L=L,
            nreg=nreg,
            dx=dx,
            eps_x=ca.vertcat(*[ca.repmat(eps[r], nreg[r], 1) for r in ("n", "s", "p")]),
            tort_x=ca.vertcat(*[ca.repmat(transport(r), nreg[r], 1) for r in ("n", "s", "p")]),
            T_ref=self.T_ref,
            cell=cell,
            inputs=given,
            i_ref=float(cell["Q_nom"]) / given["A"],
        )

    def activation(self, c: Context, key: str) -> ca.SX | float:
        """The activation energy ``key`` of B5 [J/mol]: the cell's, as the extensions change it."""
        E: ca.SX | float = c.value(key)
        for ext in self.options.extensions:
            E = ext.activation(c, key, E)
        return E

    def diffusivity_shape(self, c: Context, e: str, sto: ca.SX) -> ca.SX | float:
        """The factor on D_s of electrode ``e`` at stoichiometry ``sto`` (A1): the cell's own shape, as the
        extensions change it (1 for neither)."""
        shape = _shape(self.cell, f"D_s_{e}_shape", sto)
        for ext in self.options.extensions:
            shape = ext.solid_diffusivity(c, e, shape, sto)
        return shape

    def solid_diffusion(self, c: Context) -> None:
        """A1, A2 (and the surface value of A20): shells in ξ = r/R_s per x cell; sets f_s, surf, bulk, a_s."""
        cell, m, p, y, sl = self.cell, self.mesh, c.p, c.y, c.sl
        nr = m.n_r
        for e in ("n", "p"):
            nxe = c.nreg[e]
            sto = ca.reshape(y[sl["s" + e]], nr, nxe)  # column per x cell, row per shell
            R = p[f"R_s_{e}"]
            D = p[f"D_s_{e}"] * _arrhenius(self.activation(c, f"E_D_s_{e}"), self.T_ref, c.T1)
            cmax = float(cell[f"c_max_{e}"])
            ii = c.i_int[e]
            c.a_s[e] = 3.0 * c.value(f"eps_s_{e}") / R
            for ext in self.options.extensions:
                c.a_s[e] = ext.surface_area(c, e, c.a_s[e])
            dxi = np.diff(self.xi_c)
            rows = []
            surf_e = []
            bulk_e = []
            for k in range(nxe):
                s = sto[:, k]
                s_face = 0.5 * (s[1:] + s[:-1])
                flux = (self.xi_f[1:-1] ** 2) * self.diffusivity_shape(c, e, s_face) * (s[1:] - s[:-1]) / dxi
                flux_out = -R * ii[k] / (F * cmax * D)  # ξ² ∂ξθ at ξ = 1, from −D c_max/R ∂ξθ = i/F
                shape_surf = self.diffusivity_shape(c, e, s[-1])
                flux_full = ca.vertcat(0.0, flux, flux_out)
                dsdt = D / R**2 * (flux_full[1:] - flux_full[:-1]) / self.vol
                rows.append(dsdt)
                # surface value: quadratic through the last two shell centres with the surface gradient
                g1 = flux_out / shape_surf
                d1, d2 = self.xi_c[-1] - 1.0, self.xi_c[-2] - 1.0
                c2 = (s[-1] - s[-2] - g1 * (d1 - d2)) / (d1**2 - d2**2)
                surf_e.append(s[-1] - g1 * d1 - c2 * d1**2)
                bulk_e.append(ca.dot(s, self.vol) / self.vol.sum())
            c.f_s[e] = ca.vertcat(*rows)
            c.surf[e] = ca.vertcat(*surf_e)
            c.bulk[e] = ca.vertcat(*bulk_e)

    def electrolyte(self, c: Context) -> None:
        """A3–A8: diffusion and the reaction source in the electrolyte, zero flux at the collectors, two-point
        fluxes with harmonic means across cells and regions; sets dce and the volumetric source src = a_s i."""
        cell, p, m = self.cell, c.p, self.mesh
        tp = p["t_plus"]
        De = (
            p["D_e_scale"]
            * cell.fn("D_e", c.ce, backend="casadi")
            * _arrhenius(self.activation(c, "E_D_e"), self.T_ref, c.T1)
        )
        for ext in self.options.extensions:
            De = ext.electrolyte_property(c, "D_e", De)
        De_eff = De * c.tort_x
        half = c.dx / 2.0
        # two-point face coefficients: 1 / (Δx_i/(2k_i) + Δx_{i+1}/(2k_{i+1}))
        De_f = 1.0 / (half[:-1] / De_eff[:-1] + half[1:] / De_eff[1:])
        N_f = -De_f * (c.ce[1:] - c.ce[:-1])  # diffusive flux [mol m⁻² s⁻¹]
        N_full = ca.vertcat(c.zero, N_f, c.zero)
        c.src = ca.vertcat(a_s_i(c, "n"), ca.SX.zeros(m.n_s), a_s_i(c, "p"))  # a i [A m⁻³]
        c.dce = (-(N_full[1:] - N_full[:-1]) / c.dx + (1.0 - tp) * c.src / F) / c.eps_x / C_SCALE

    def charge(self, c: Context) -> None:
        """A9–A16: charge conservation in the electrolyte (with the concentration overpotential) and in the
        solids; φ_s(0) = 0 is the potential reference, I/A enters at x = L; sets g_e, g_s and φ_s(L)."""
        cell, p = self.cell, c.p
        tp = p["t_plus"]
        kap = (
            p["kappa_scale"]
            * cell.fn("kappa", c.ce, backend="casadi")
            * _arrhenius(self.activation(c, "E_kappa"), self.T_ref, c.T1)
        )
        dlnf = p["dlnf_scale"] * cell.fn("dlnf", c.ce, backend="casadi")
        for ext in self.options.extensions:
            kap = ext.electrolyte_property(c, "kappa", kap)
            dlnf = ext.electrolyte_property(c, "dlnf", dlnf)
        tdf = 1.0 + dlnf
        kap_eff = kap * c.tort_x
        half = c.dx / 2.0
        kap_f = 1.0 / (half[:-1] / kap_eff[:-1] + half[1:] / kap_eff[1:])
        tdf_f = 0.5 * (tdf[:-1] + tdf[1:])
        phie = c.phie
        dlnc = ca.log(c.ce[1:]) - ca.log(c.ce[:-1])
        ie_f = -kap_f * ((phie[1:] - phie[:-1]) - 2.0 * R_GAS * c.T1 / F * (1.0 - tp) * tdf_f * dlnc)
        ie_full = ca.vertcat(c.zero, ie_f, c.zero)
        src = c.src
        for ext in self.options.extensions:
            for e in ("n", "p"):
                cap = ext.capacitive_current(c, e)
                if cap is not None:
                    c.capacitive[e] = c.capacitive[e] + cap if e in c.capacitive else cap
        if c.capacitive:  # charges the double layer: in the charge balance, not in the electrolyte's lithium
            zn, zp = ca.SX.zeros(c.nreg["n"]), ca.SX.zeros(c.nreg["p"])
            src = src + ca.vertcat(c.capacitive.get("n", zn), ca.SX.zeros(c.nreg["s"]), c.capacitive.get("p", zp))
        c.g_e = ((ie_full[1:] - ie_full[:-1]) - src * c.dx) / c.i_ref
        for e in ("n", "p"):
            phis = c.y[c.sl[f"phis_{e}"]]
            h = c.L[e] / c.nreg[e]
            sig = p[f"sigma_{e}"] * c.value(f"eps_s_{e}") ** float(cell[f"brugg_s_{e}"])
            is_f = -sig * (phis[1:] - phis[:-1]) / h
            if e == "n":
                left = -sig * (phis[0] - 0.0) / (h / 2.0)  # φ_s(0) = 0: the potential reference
                right = c.zero
            else:
                left = c.zero
                right = c.i_app
                c.phis_L = phis[-1] - (h / 2.0) * c.i_app / sig  # φ_s(L) from the collector's current
            is_full = ca.vertcat(left, is_f, right)
            reaction = a_s_i(c, e) + c.capacitive[e] if e in c.capacitive else a_s_i(c, e)
            c.g_s[e] = ((is_full[1:] - is_full[:-1]) + reaction * h) / c.i_ref

    def kinetics(self, c: Context) -> None:
        """A17–A20: Butler–Volmer with α_a = α_c = 0.5 and the film resistance; sets g_bv, and the potentials at
        each electrode's mean bulk stoichiometry for the heat (B3–B4): U_bulk, dUdT_bulk."""
        cell, m, p = self.cell, self.mesh, c.p
        off = {"n": 0, "p": m.n_n + m.n_s}
        for e in ("n", "p"):
            nxe = c.nreg[e]
            cmax = float(cell[f"c_max_{e}"])
            k = p[f"k_{e}"] * _arrhenius(self.activation(c, f"E_k_{e}"), self.T_ref, c.T1)
            ce_e = c.ce[off[e] : off[e] + nxe]
            css = c.surf[e] * cmax
            i0 = k * ca.sqrt(ca.fmax(css, 1e-6) * ca.fmax(cmax - css, 1e-6) * ca.fmax(ce_e, 1e-6))
            U = cell.fn(f"U_{e}", c.surf[e], backend="casadi")
            for ext in self.options.extensions:
                U = ext.open_circuit(c, e, U)
            U = U + edge_potential(c.surf[e], c.T1)
            # a film's ionic conduction is thermally activated: R_f = R_f,ref / exp[(E/R)(1/T_ref − 1/T₁)]
            R_f = p[f"R_f_{e}"] / _arrhenius(self.activation(c, f"E_R_f_{e}"), self.T_ref, c.T1)
            eta = c.y[c.sl[f"phis_{e}"]] - c.phie[off[e] : off[e] + nxe] - U - R_f * c.i_int[e]
            c.g_bv[e] = (c.i_int[e] - 2.0 * i0 * ca.sinh(F * eta / (2.0 * R_GAS * c.T1))) / c.i_ref
            c.U[e] = U
            # B3-B4: the potentials at the electrode's mean bulk stoichiometry (one evaluation per electrode)
            sign = 1.0 if e == "p" else -1.0
            mean_bulk = ca.sum1(c.bulk[e]) / nxe
            U_mean = cell.fn(f"U_{e}", mean_bulk, backend="casadi")
            for ext in self.options.extensions:
                U_mean = ext.bulk_open_circuit(c, e, U_mean, mean_bulk)
            c.U_bulk = c.U_bulk + sign * U_mean
            c.dUdT_bulk = c.dUdT_bulk + sign * cell.fn(f"dUdT_{e}", mean_bulk, backend="casadi")

    def voltage(self, c: Context) -> None:
        """A21: V = φ_s(L) − φ_s(0) − R_c I (φ_s(0) = 0)."""
        c.V = c.phis_L - float(self.cell["R_c"]) * c.I_dis
        for ext in self.options.extensions:
            c.V = ext.voltage(c, c.V)

    def thermal(self, c: Context) -> None:
        """B1–B3: two-node lumped thermal model with Bernardi's heat Q = I (U_bulk − V) − I T₁ ∂U_bulk/∂T (the
        Arrhenius law B5 enters the blocks above); sets Q, dT1, dT2 (zero when isothermal)."""
        th: dict[str, ca.SX | float] = {"dUdT": c.dUdT_bulk}
        th |= {k: c.value(k) for k in ("C1", "C2", "h12", "h2a")}
        for ext in self.options.extensions:
            th = ext.heat(c, th)
        c.Q = c.I_dis * (c.U_bulk - c.V) - c.I_dis * c.T1 * th["dUdT"]
        if self.isothermal:
            c.dT1 = ca.SX(0.0)
            c.dT2 = ca.SX(0.0)
        else:
            h12, h2a = th["h12"], th["h2a"]
            c.dT1 = (h12 * (c.T2 - c.T1) + c.Q) / th["C1"]
            c.dT2 = (h12 * (c.T1 - c.T2) + h2a * (c.T_amb - c.T2)) / th["C2"]

    def lithium(self, y: np.ndarray, theta_bar: np.ndarray) -> float:
        """Moles of lithium in solid + electrolyte at state y (for conservation checks)."""
        cell, m, sl = self.cell, self.mesh, self.layout.slices()
        p = {s.name: s.denormalise(float(v)) for s, v in zip(parameters.DYNAMIC, theta_bar, strict=True)}
        A = float(cell["A"])
        total = 0.0
        for e, n in (("n", m.n_n), ("p", m.n_p)):
            sto = np.reshape(y[sl["s" + e]], (n, m.n_r))  # column-major reshape in CasADi = rows here
            mean = sto @ self.vol / self.vol.sum()
            h = float(cell[f"L_{e}"]) / n
            total += float(np.sum(mean)) * h * A * float(cell[f"eps_s_{e}"]) * float(cell[f"c_max_{e}"])
        ce = y[sl["ce"]] * C_SCALE
        for r, start, n in (("n", 0, m.n_n), ("s", m.n_n, m.n_s), ("p", m.n_n + m.n_s, m.n_p)):
            h = float(cell[f"L_{r}"]) / n
            total += float(np.sum(ce[start : start + n])) * h * A * p[f"eps_e_{r}"]
        return total
