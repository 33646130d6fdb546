"""The 18 identified dynamic parameters (paper Tables 2, 4, 11), the parameters of the model extensions, and
their normalisation (eq. 1).

Bounds apply to identification only: :func:`normalise` and :func:`denormalise` accept values outside [0, 1].
An extension's parameters are named ``KEY.NAME`` (``contact_resistance.R_c``) among the identified ones; inside
the extension (``Cell.with_extension``, ``Cell.extensions``, BPX) they are ``NAME``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from protocols.errors import InputError
from protocols.steps import did_you_mean


class Scale(Enum):
    """How a parameter is normalised to θ̄ (eq. 1)."""

    LOG = "log"
    LINEAR = "linear"


@dataclass(frozen=True)
class ParameterSpec:
    """One identified parameter: name, symbol, unit, bounds, nominal and the paper's Table 11 result."""

    name: str
    symbol: str
    unit: str
    lower: float
    upper: float
    nominal: float
    truth: float
    scale: Scale
    description: str

    def normalise(self, value: float) -> float:
        """θ̄ from θ (eq. 1)."""
        if self.scale is Scale.LOG:
            if value <= 0:
                raise InputError(f"{self.name} must be positive for log normalisation, got {value}")
            return (math.log(value) - math.log(self.lower)) / (math.log(self.upper) - math.log(self.lower))
        return (value - self.lower) / (self.upper - self.lower)

    def denormalise(self, theta_bar: float) -> float:
        """θ from θ̄ (inverse of eq. 1)."""
        if self.scale is Scale.LOG:
            return math.exp(math.log(self.lower) + theta_bar * (math.log(self.upper) - math.log(self.lower)))
        return self.lower + theta_bar * (self.upper - self.lower)

    def dvalue_dnormalised(self, value: float) -> float:
        """dθ/dθ̄ at θ: the chain-rule factor from physical to normalised sensitivities."""
        if self.scale is Scale.LOG:
            return value * (math.log(self.upper) - math.log(self.lower))
        return self.upper - self.lower


_L, _N = Scale.LOG, Scale.LINEAR

#: The registry, in the paper's Table 2 order. Units: SI.
DYNAMIC: tuple[ParameterSpec, ...] = (
    ParameterSpec("D_s_n", "D_s⁻", "m2/s", 2.25e-16, 1.05e-12, 3.90e-14, 2.634e-14, _L, "negative solid diffusivity"),
    ParameterSpec("D_s_p", "D_s⁺", "m2/s", 2.00e-16, 1.00e-12, 1.00e-13, 6.625e-14, _L, "positive solid diffusivity"),
    ParameterSpec("R_s_n", "R_s⁻", "m", 1.0e-6, 1.0e-4, 10.9e-6, 20.235e-6, _N, "negative particle radius"),
    ParameterSpec("R_s_p", "R_s⁺", "m", 1.0e-6, 1.0e-4, 10.9e-6, 17.163e-6, _N, "positive particle radius"),
    ParameterSpec("sigma_n", "σ⁻", "S/m", 50.0, 500.0, 100.0, 500.0, _L, "negative solid conductivity"),
    ParameterSpec("sigma_p", "σ⁺", "S/m", 50.0, 500.0, 100.0, 500.0, _L, "positive solid conductivity"),
    ParameterSpec("D_e_scale", "D_e(·)", "1", 0.5, 1.5, 1.0, 1.195, _N, "electrolyte diffusivity factor"),
    ParameterSpec("eps_e_n", "ε_e⁻", "1", 0.18, 0.45, 0.3, 0.289, _N, "negative electrolyte volume fraction"),
    ParameterSpec("eps_e_s", "ε_e^sep", "1", 0.45, 0.5, 0.5, 0.468, _N, "separator electrolyte volume fraction"),
    ParameterSpec("eps_e_p", "ε_e⁺", "1", 0.18, 0.33, 0.3, 0.307, _N, "positive electrolyte volume fraction"),
    ParameterSpec("kappa_scale", "κ(·)", "1", 0.5, 1.5, 1.0, 1.398, _N, "electrolyte conductivity factor"),
    ParameterSpec("t_plus", "t_c⁰", "1", 0.36, 0.363, 0.363, 0.36, _N, "cation transference number"),
    ParameterSpec("dlnf_scale", "dlnf/dlnc_e(·)", "1", 0.5, 1.5, 1.0, 0.573, _N, "activity term factor"),
    ParameterSpec("k_n", "k⁻", "A/m2 (m3/mol)^1.5", 7.5e-5, 7.5e-3, 7.5e-4, 7.5e-5, _L, "negative rate constant"),
    ParameterSpec("k_p", "k⁺", "A/m2 (m3/mol)^1.5", 2.3e-4, 2.3e-2, 2.3e-3, 2.3e-4, _L, "positive rate constant"),
    ParameterSpec("R_f_n", "R_f⁻", "Ohm m2", 1.0e-5, 1.0e-3, 5.0e-4, 8.719e-5, _N, "negative film resistance"),
    ParameterSpec("R_f_p", "R_f⁺", "Ohm m2", 1.0e-4, 1.0e-3, 1.0e-3, 4.619e-4, _N, "positive film resistance"),
    ParameterSpec("c_e0", "c_e(x,0)", "mol/m3", 500.0, 1500.0, 1000.0, 1500.0, _N, "initial electrolyte concentration"),
)

#: Name → spec.
SPECS: dict[str, ParameterSpec] = {p.name: p for p in DYNAMIC}
NAMES: tuple[str, ...] = tuple(SPECS)

#: Table 4 / 11 equilibrium parameters (identified from the OCV test, not normalised).
EQUILIBRIUM_TRUTH: dict[str, float] = {"eps_s_n": 0.5438895, "eps_s_p": 0.6663649, "n_Li": 0.1406}


@dataclass(frozen=True)
class ExtensionParameter(ParameterSpec):
    """A parameter of a model extension: ``off`` is the value at which the extension is the base model exactly
    (its nominal and truth), ``citation`` the model it comes from; ``shapes``: it only shapes the effect (a rate or
    exponent), so it has none while the sizes are at ``off``. Always normalised linearly (``off`` may be 0)."""

    extension: str = ""
    off: float = 0.0
    citation: str = ""
    shapes: bool = False

    @property
    def qualified(self) -> str:
        """Its name among the identified parameters: ``KEY.NAME``."""
        return f"{self.extension}.{self.name}"


def _ext(
    key: str, name: str, unit: str, lower: float, upper: float, off: float, what: str, cite: str, shapes: bool = False
) -> ExtensionParameter:
    return ExtensionParameter(name, name, unit, lower, upper, off, off, _N, what, key, off, cite, shapes)


_GUO = "M. Guo, G. Sikha, R. E. White, J. Electrochem. Soc. 158 (2011) A122 (contact resistance in a P2D model)"
_PYBAMM = "PyBaMM lithium_ion options: 'contact resistance' (Sulzer et al., J. Open Res. Softw. 9 (2021) 14)"
_AXEN = (
    "one-state hysteresis: J. B. Axen, X. Chen, M. Fleischer, Energy Storage 4 (2022) e358; PyBaMM's "
    "'open-circuit potential': 'one-state hysteresis'"
)
_ZHANG = "Arrhenius activation energies as in Q. Zhang et al., J. Power Sources 270 (2014) 367 (the cell's own values)"
_LIN = "two-state lumped thermal model: X. Lin et al., J. Power Sources 257 (2014) 1 (heat capacities, heat transfer)"
_SEI = (
    "SEI growth, reaction limited: PyBaMM's 'SEI': 'reaction limited (asymmetric)' without film resistance (Marquis, "
    "DPhil thesis, Oxford 2020, eq. 5.92; Safari et al., J. Electrochem. Soc. 156 (2009) A145)"
)
_LAM = "loss of active material at a constant rate (cf. PyBaMM's 'loss of active material'; Reniers et al. 2019)"
_VR = (
    "concentration dependence of LiPF6 electrolytes: L. O. Valoen, J. N. Reimers, J. Electrochem. Soc. 152 (2005) A882"
)
_OCP = (
    "electrode balancing: OCP stoichiometry shifts and offset (Mohtat et al. 2019, as cited by PyBaMM's electrode SOH)"
)
_DL = "double layer in the differential surface form: PyBaMM 'surface form': 'differential' (Sulzer et al. 2021)"
_SENSOR = "measurement model: a linear current sensor with offset and gain error (e.g. Arbin/Maccor specifications)"

#: The model extensions and their parameters, by catalog key (the ``cause`` keys of ``battlab diagnose``).
EXTENSIONS: dict[str, tuple[ExtensionParameter, ...]] = {
    "contact_resistance": (
        _ext("contact_resistance", "R_c", "Ohm", 0.0, 0.02, 0.0, "series contact resistance at T_ref", _GUO),
        _ext("contact_resistance", "dRc_dT", "Ohm/K", -2e-4, 2e-4, 0.0, "its temperature coefficient", _PYBAMM),
    ),
    "current_sensor": (
        _ext("current_sensor", "offset", "A", -0.05, 0.05, 0.0, "offset of the logged current (+ = charge)", _SENSOR),
        _ext("current_sensor", "gain", "1", -0.02, 0.02, 0.0, "relative gain error of the logged current", _SENSOR),
    ),
    "thermal": (
        *(
            _ext(
                "thermal", f"dE_{k}", "J/mol", -30000.0, 30000.0, 0.0, f"change of the activation energy E_{k}", _ZHANG
            )
            for k in ("D_s_n", "D_s_p", "k_n", "k_p", "D_e", "kappa")
        ),
        _ext("thermal", "h2a_scale", "1", 0.25, 4.0, 1.0, "factor on the surface-to-ambient heat transfer h2a", _LIN),
        _ext("thermal", "C_scale", "1", 0.25, 4.0, 1.0, "factor on the heat capacities C1 and C2", _LIN),
        _ext("thermal", "dUdT_offset", "V/K", -3e-4, 3e-4, 0.0, "offset of the cell's entropic coefficient", _LIN),
    ),
    "equilibrium": (
        _ext("equilibrium", "d_sto_n", "1", -0.05, 0.05, 0.0, "shift of the negative OCP in stoichiometry", _OCP),
        _ext("equilibrium", "d_sto_p", "1", -0.05, 0.05, 0.0, "shift of the positive OCP in stoichiometry", _OCP),
        _ext("equilibrium", "dU", "V", -0.02, 0.02, 0.0, "offset of the open-circuit voltage", _OCP),
    ),
    "hysteresis": (
        _ext("hysteresis", "M_n", "V", 0.0, 0.05, 0.0, "negative OCP hysteresis half-width", _AXEN),
        _ext(
            "hysteresis",
            "gamma_n",
            "1",
            1.0,
            200.0,
            50.0,
            "negative hysteresis decay rate per stoichiometry",
            _AXEN,
            True,
        ),
        _ext("hysteresis", "M_p", "V", 0.0, 0.05, 0.0, "positive OCP hysteresis half-width", _AXEN),
        _ext(
            "hysteresis",
            "gamma_p",
            "1",
            1.0,
            200.0,
            50.0,
            "positive hysteresis decay rate per stoichiometry",
            _AXEN,
            True,
        ),
    ),
    "double_layer": (
        _ext("double_layer", "C_dl_n", "F/m2", 0.0, 2.0, 0.0, "negative double-layer capacitance", _DL),
        _ext("double_layer", "C_dl_p", "F/m2", 0.0, 2.0, 0.0, "positive double-layer capacitance", _DL),
    ),
    "capacity_fade": (
        _ext("capacity_fade", "I_side", "A", 0.0, 1.0, 0.0, "lithium-consuming side-reaction current at 0.1 V", _SEI),
        _ext(
            "capacity_fade",
            "alpha_side",
            "1",
            0.0,
            1.0,
            0.0,
            "side reaction's cathodic transfer coefficient",
            _SEI,
            True,
        ),
        _ext("capacity_fade", "lam_n", "1/h", 0.0, 0.01, 0.0, "negative active-material loss rate", _LAM),
        _ext("capacity_fade", "lam_p", "1/h", 0.0, 0.01, 0.0, "positive active-material loss rate", _LAM),
    ),
    "electrolyte": (
        _ext("electrolyte", "De_slope", "1", -1.0, 1.0, 0.0, "relative slope of D_e in c_e/1000 mol m-3", _VR),
        _ext("electrolyte", "kappa_slope", "1", -1.0, 1.0, 0.0, "relative slope of kappa in c_e/1000 mol m-3", _VR),
        _ext("electrolyte", "dlnf_slope", "1", -1.0, 1.0, 0.0, "relative slope of dlnf in c_e/1000 mol m-3", _VR),
    ),
}

#: Qualified name (``KEY.NAME``) → extension parameter.
EXTENSION_SPECS: dict[str, ExtensionParameter] = {p.qualified: p for ps in EXTENSIONS.values() for p in ps}


def extension_parameters(key: str) -> tuple[ExtensionParameter, ...]:
    """The parameters of a catalog extension; an unknown key is an :class:`InputError` listing the known ones."""
    try:
        return EXTENSIONS[key]
    except KeyError:
        raise InputError(
            f"unknown model extension {key!r}{did_you_mean(key, list(EXTENSIONS))}; expected one of "
            f"{', '.join(EXTENSIONS)}"
        ) from None


def spec(name: str) -> ParameterSpec:
    """The spec of an identified parameter (one of the 18, or ``KEY.NAME`` of an extension); an unknown name is an
    :class:`InputError` listing the known ones."""
    try:
        return SPECS[name] if name in SPECS else EXTENSION_SPECS[name]
    except KeyError:
        hint = did_you_mean(name, [*NAMES, *EXTENSION_SPECS])
        raise InputError(
            f"unknown parameter {name!r}{hint}; expected one of {', '.join(NAMES)} or an extension's KEY.NAME "
            f"({', '.join(EXTENSION_SPECS)})"
        ) from None


def check_names(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Validate a list of identified parameter names (the 18 and extensions' ``KEY.NAME``; no duplicates)."""
    out = tuple(names)
    for n in out:
        spec(n)
    dup = {n for n in out if out.count(n) > 1}
    if dup:
        raise InputError(f"parameter(s) {sorted(dup)} given more than once")
    return out


#: The paper's Table 9: the parameter groups 1–4 it identified one after the other (its cell, its normalisation).
TABLE9_GROUPS: tuple[tuple[str, ...], ...] = (
    ("R_s_n", "R_s_p"),
    ("D_s_n", "D_s_p", "eps_e_n", "kappa_scale", "D_e_scale", "dlnf_scale"),
    ("R_f_n", "k_n", "eps_e_p", "c_e0", "R_f_p"),
    ("sigma_n", "sigma_p", "eps_e_s", "k_p", "t_plus"),
)
