"""The 18 identified dynamic parameters (paper Tables 2, 4, 11), the parameters of the model extensions, and
their normalisation (eq. 1).

Bounds apply to identification only: :func:`normalise` and :func:`denormalise` accept values outside [0, 1].
An extension's parameters are named ``KEY.NAME`` (``contact_resistance.R_c``) among the identified ones; inside
the extension (``Cell.with_extension``, ``Cell.extensions``, BPX) they are ``NAME``. They are declared by their
causes (:mod:`battlab.causes`); :data:`EXTENSIONS` is derived from that catalog.
"""

from __future__ import annotations

from battlab.causes import extended
from battlab.specs import ExtensionParameter, ParameterSpec, Scale
from protocols.errors import InputError
from protocols.steps import did_you_mean

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

#: Values of a cell that the compiled model takes as inputs beside θ̄, so that cells that differ only in them share
#: one compiled model instead of compiling one per trial point: the equilibrium fit moves the electrode moles
#: (through ε_s±, and the area A where they need more room); a thermal fit the heat capacities and transfer
#: coefficients (B1–B3); an Arrhenius fit the activation energies (B5, and the films' of A19).
MODEL_INPUTS: tuple[str, ...] = (
    "A",
    "eps_s_n",
    "eps_s_p",
    "C1",
    "C2",
    "h12",
    "h2a",
    "E_D_s_n",
    "E_D_s_p",
    "E_k_n",
    "E_k_p",
    "E_D_e",
    "E_kappa",
    "E_R_f_n",
    "E_R_f_p",
)
#: Values the model's equations never read (the start state is made from them in Python): the cyclable lithium
#: and the stoichiometry window.
START_STATE_ONLY: tuple[str, ...] = ("n_Li", "sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100")


#: The model extensions' parameters, by catalog key (the ``cause`` keys of ``battlab diagnose``), in catalog order.
EXTENSIONS: dict[str, tuple[ExtensionParameter, ...]] = {c.key: c.parameters for c in extended()}

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

__all__ = [
    "DYNAMIC",
    "EQUILIBRIUM_TRUTH",
    "EXTENSIONS",
    "EXTENSION_SPECS",
    "NAMES",
    "SPECS",
    "TABLE9_GROUPS",
    "ExtensionParameter",
    "ParameterSpec",
    "Scale",
    "check_names",
    "extension_parameters",
    "spec",
]
