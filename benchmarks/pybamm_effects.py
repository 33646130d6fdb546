"""Logged data with one hidden effect made by PyBaMM (a model battlab did not write): the benchmark ``battlab
diagnose`` is measured and calibrated on (benchmarks/bench_diagnose_pybamm.py runs it).

Each case is PyBaMM's DFN with lumped thermal model on the BPX NMC pouch cell (12.5 Ah,
``pybamm.ParameterValues.create_from_bpx``), 4 h at 1 s (:func:`make_profile`: pulses of both directions each followed
by a rest, at several SOCs reached by constant-current moves, and drive-cycle stretches), with one hidden effect the
cell file does not describe, or none (the nulls, each on its own profile). The current reaches PyBaMM exactly, as a
sum of Heaviside steps (PyBaMM stops its integration at every switch); its "Discharge capacity [A.h]" is checked
against the integral of the current it was fed and against the integral of the logged current, and a case where
either differs is refused. The log carries 1 mV of white noise on the voltage and the virtual tester's quantisation
(:data:`NOISE`), the tester's current noise, and 0.05 K on the surface temperature (PyBaMM's lumped temperature);
it is written as BDF CSV with its sidecar (start SOC, source) beside the cell file battlab diagnoses it with.

The effects and the catalog key each expects (:data:`CASES`; two sizes or forms each):

- ``capacity_fade``: active material lost since the cell was parameterised (PyBaMM's active material volume fraction
  lowered at the same start stoichiometry), positive and negative; a reaction-limited SEI consuming lithium;
- ``electrolyte``: slower electrolyte diffusion, with or without a lower conductivity;
- ``thermal``: a cell cooled where its file says adiabatic, and the reverse (the surface temperature is logged);
- ``contact_resistance``: PyBaMM's series contact resistance;
- ``hysteresis``: PyBaMM's one-state hysteresis on the negative electrode;
- ``solid_diffusion``: a particle diffusivity that varies with the stoichiometry (log-linear), negative or positive;
- ``kinetics``: both electrodes' exchange-current densities scaled;
- ``double_layer``: PyBaMM's differential surface form;
- ``current_sensor``: PyBaMM fed the true current, the log holds (1 + gain) I + offset;
- ``equilibrium``: more lithium in the negative electrode at the start than the logged SOC implies (its
  stoichiometry shifted), and the positive electrode's OCP curve offset.

Generation is slow (PyBaMM took 1.5-15 min per case on 2 cores shared at a load of 10-16), so it is cached: ``python
benchmarks/pybamm_effects.py --data DIR`` makes, per case, ``NAME.bdf.csv`` with its sidecar, ``NAME.bpx.json`` (the
cell file to diagnose with), ``NAME.truth.npz`` (PyBaMM's noise-free solution) and ``NAME.case.json`` (the case's
definition, its key and what the generation measured, written last), and makes a case again only when a file is
missing or its definition (:meth:`Case.key`) changed. ``--cases a,b`` makes a part, ``--workers N`` uses a process
pool (default 1), ``--nice`` lowers the priority (default 10).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import sys
import tempfile
import time
import warnings
import zlib
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pybamm_reference import hysteresis_in_pybamm, pybamm_zoh  # noqa: E402

from drivers.virtual.noise import NoiseModel  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BPX = Path(os.environ.get("BATTLAB_DATA", ROOT.parent / "shared" / "data")) / "bpx" / "nmc_pouch_cell_BPX.json"
#: bump when a change of this module changes the data a case definition makes (every cached case is made again)
GENERATOR = 1
#: PyBaMM's mesh points per domain and IDAKLU tolerances: 20 points are within 0.5 mV of battlab's mesh on this cell
#: (tests/battlab/diagnose/test_diagnose_pybamm.py); atol 1e-6 moves the voltage by < 10 µV from 1e-8 and is 30 %
#: faster
VAR_PTS = {k: 20 for k in ("x_n", "x_s", "x_p", "r_n", "r_p")}
RTOL, ATOL = 1e-6, 1e-6
#: the tester reads the voltage this long [s] after it sets a sample's current: PyBaMM's solution is read there (a
#: double layer has relaxed by then, as it has for any tester logging at 1 s; everything else moves by microvolts)
READ = 0.01
AMBIENT_K = 298.15
#: the cell's cooling [W m⁻² K⁻¹] in the cell file and in PyBaMM (natural convection; the BPX file gives none)
H_COOL = 10.0
#: PyBaMM's voltage cut-offs [V], wider than the file's 2.7-4.2 V: a hidden resistance may push a pulse past them,
#: and the diagnosis replays logged data in a window widened by 0.15 V
V_CUTOFF = (2.55, 4.35)
#: the log's noise: 1 mV white on the voltage with the tester's 100 µV quantisation (no current-dependent part, no
#: sampling jitter), the tester's current noise, 0.05 K on the surface temperature with 0.01 K quantisation
NOISE = NoiseModel(voltage_white_V=1e-3, voltage_per_amp_V=0.0, sample_jitter_s=0.0)
#: the largest gaps [Ah] allowed between PyBaMM's discharge capacity and the integral of the current it was fed
#: (solver), and of the logged current (its noise integrates to about 1e-5 Ah over 4 h)
CHARGE_TOL_SOLVER = 1e-5
CHARGE_TOL_LOG = 2e-4


# ---------------------------------------------------------------------------------------------------------------
# profiles
@dataclass(frozen=True)
class ProfileSpec:
    """A test profile: ``seed`` draws its blocks, ``soc0`` is its start SOC, ``drives`` the drive cycles its drive
    stretches are cut from (:class:`protocols.Cycle` names), ``drive_share`` the chance that the next block is a drive
    stretch rather than pulses, ``duration`` [s]."""

    seed: int
    soc0: float
    drives: tuple[str, ...]
    drive_share: float = 0.6
    duration: float = 14400.0


#: SOC window the profile stays in (by the nominal capacity)
SOC_LO, SOC_HI = 0.12, 0.95


def make_profile(q: float, spec: ProfileSpec) -> Any:
    """A 1 s profile for a cell of ``q`` [Ah] (positive = charge): a 10 min rest, then cycles until ``duration``,
    each of pulse pairs (2-3 pairs, discharge and charge in random order, 0.5-3C for 10-120 s, at most 120 C·s each,
    at most 1C towards the nearer end of the window; every pulse followed by a 2-6 min rest), with chance
    ``drive_share`` a drive-cycle stretch (7-12 min of the library's drive current for a 2.7 Ah cell scaled to ``q``,
    peaks at most 3C, then a 5-10 min rest), and a constant-current move at 0.5-1C to another SOC level 15-35 %
    away, then a 10 min rest. Ends with a rest. Raises when the SOC leaves the window."""
    from protocols import Cycle, Profile, drive_profile

    rng = np.random.default_rng(spec.seed)
    n_total = int(spec.duration)
    parts: list[np.ndarray] = []
    soc = spec.soc0

    def add(current: np.ndarray) -> None:
        nonlocal soc
        parts.append(np.asarray(current, float))
        soc += float(np.sum(current)) / 3600.0 / q

    def rest(lo: float, hi: float) -> None:
        add(np.zeros(int(rng.uniform(lo, hi) // 10 * 10)))

    def pulses() -> None:
        for _ in range(int(rng.integers(2, 4))):
            for sign in rng.permutation([-1.0, 1.0]):
                towards_end = (sign > 0 and soc > 0.8) or (sign < 0 and soc < 0.25)
                c = float(rng.choice([0.5, 1.0]) if towards_end else rng.choice([0.5, 1.0, 2.0, 3.0]))
                widths = [w for w in (10, 30, 60, 120) if c * w <= 120.0]
                add(np.full(int(rng.choice(widths)), sign * c * q))
                rest(120.0, 360.0)

    def drive() -> None:
        base = drive_profile(Cycle[str(rng.choice(spec.drives))]).current[:-1]
        peak_c = float(np.max(np.abs(base))) / 2.7
        scale = min(float(rng.uniform(0.6, 1.0)), 3.0 / peak_c) * q / 2.7
        n = int(rng.uniform(420.0, 720.0))
        start = int(rng.integers(0, max(base.size - n, 1)))
        add(scale * base[start : start + n])
        rest(300.0, 600.0)

    def move() -> None:
        levels = [x for x in (0.2, 0.35, 0.5, 0.65, 0.8, 0.9) if 0.15 <= abs(x - soc) <= 0.35]
        target = float(rng.choice(levels))
        c = float(rng.uniform(0.5, 1.0))
        add(np.full(int(abs(target - soc) * 3600.0 / c), np.sign(target - soc) * c * q))
        rest(600.0, 601.0)

    def length() -> int:
        return sum(p.size for p in parts)

    add(np.zeros(600))
    while length() < n_total - 900:
        pulses()
        if soc > 0.3 and rng.uniform() < spec.drive_share and length() < n_total - 1200:
            drive()
        if length() < n_total - 2400:
            move()
    cur = np.concatenate(parts)[:n_total]
    cur = np.concatenate([cur, np.zeros(n_total + 1 - cur.size)])
    soc_t = spec.soc0 + np.concatenate([[0.0], np.cumsum(cur[:-1])]) / 3600.0 / q
    if soc_t.min() < SOC_LO or soc_t.max() > SOC_HI:
        raise ValueError(f"profile {spec}: SOC {soc_t.min():.2f}-{soc_t.max():.2f} leaves {SOC_LO}-{SOC_HI}")
    return Profile(np.arange(n_total + 1, dtype=float), cur, id=f"pybamm-bench-{spec.seed}", soc0=spec.soc0)


#: the nulls' profiles: different seeds, start SOCs, drive cycles and mixes (the effect cases reuse them in turn)
PROFILES: tuple[ProfileSpec, ...] = (
    ProfileSpec(1, 0.80, ("UDDS", "US06"), drive_share=0.7),
    ProfileSpec(2, 0.50, ("HWFET", "WLTC3B"), drive_share=0.5),
    ProfileSpec(3, 0.35, ("DC1", "DC2"), drive_share=0.9),
    ProfileSpec(4, 0.90, ("UDDS", "HWFET"), drive_share=0.7),
    ProfileSpec(5, 0.65, ("US06", "DC1"), drive_share=0.4),
    ProfileSpec(6, 0.45, ("WLTC3B", "UDDS"), drive_share=0.6),
)


# ---------------------------------------------------------------------------------------------------------------
# effects as PyBaMM options and values
@dataclass(frozen=True)
class Effect:
    """A hidden effect: its ``kind`` (a key of :data:`EFFECTS`) and its numbers (``values``: name, value pairs)."""

    kind: str = "none"
    values: tuple[tuple[str, Any], ...] = ()

    def __getitem__(self, name: str) -> Any:
        return dict(self.values)[name]


def _scaled(fn: Any, factor: float) -> Any:
    """A PyBaMM parameter function (or number) times ``factor``."""
    return (lambda *a: factor * fn(*a)) if callable(fn) else factor * fn


def _lam(e: Effect, pv: Any) -> tuple[dict, dict]:
    key = f"{e['electrode']} electrode active material volume fraction"
    return {}, {key: pv[key] * (1.0 - e["fraction"])}


#: the SEI parameters PyBaMM's reaction-limited model reads (Chen 2020's set, which the BPX file has not)
SEI = {
    "Ratio of lithium moles to SEI moles": 2.0,
    "SEI partial molar volume [m3.mol-1]": 9.585e-05,
    "SEI resistivity [Ohm.m]": 200000.0,
    "SEI open-circuit potential [V]": 0.4,
    "Initial SEI thickness [m]": 5e-09,
    "SEI growth activation energy [J.mol-1]": 0.0,
}


def _sei(e: Effect, pv: Any) -> tuple[dict, dict]:
    return {"SEI": "reaction limited", "SEI film resistance": "none"}, {
        **SEI,
        "SEI reaction exchange current density [A.m-2]": e["j0"],
    }


def _electrolyte(e: Effect, pv: Any) -> tuple[dict, dict]:
    d, k = "Electrolyte diffusivity [m2.s-1]", "Electrolyte conductivity [S.m-1]"
    return {}, {d: _scaled(pv[d], e["D_e"]), k: _scaled(pv[k], e["kappa"])}


def _contact(e: Effect, pv: Any) -> tuple[dict, dict]:
    return {"contact resistance": "true"}, {"Contact resistance [Ohm]": e["R"]}


def _hysteresis(e: Effect, pv: Any) -> tuple[dict, dict]:
    return hysteresis_in_pybamm(pv["Negative electrode OCP [V]"], e["M"], e["gamma"])


def _diffusivity(e: Effect, pv: Any) -> tuple[dict, dict]:
    import pybamm

    key = f"{e['electrode']} particle diffusivity [m2.s-1]"
    old, b = pv[key], e["b"]
    return {}, {key: lambda sto, T: old(sto, T) * pybamm.exp(b * (sto - 0.5))}


def _kinetics(e: Effect, pv: Any) -> tuple[dict, dict]:
    keys = [f"{s} electrode exchange-current density [A.m-2]" for s in ("Negative", "Positive")]
    return {}, {k: _scaled(pv[k], e["factor"]) for k in keys}


def _double_layer(e: Effect, pv: Any) -> tuple[dict, dict]:
    return {"surface form": "differential"}, {
        f"{s} electrode double-layer capacity [F.m-2]": e["C_dl"] for s in ("Negative", "Positive")
    }


def _initial_lithium(e: Effect, pv: Any) -> tuple[dict, dict]:
    s = e["electrode"]
    key = f"Initial concentration in {s.lower()} electrode [mol.m-3]"
    return {}, {key: pv[key] + e["d_sto"] * pv[f"Maximum concentration in {s.lower()} electrode [mol.m-3]"]}


def _ocp_offset(e: Effect, pv: Any) -> tuple[dict, dict]:
    key = f"{e['electrode']} electrode OCP [V]"
    old, dU = pv[key], e["dU"]
    return {}, {key: lambda *a: old(*a) + dU}


def _nothing(e: Effect, pv: Any) -> tuple[dict, dict]:
    return {}, {}


#: what each kind of effect asks of PyBaMM: (options, parameter values) from the effect and the BPX cell's values.
#: ``thermal`` and ``sensor`` change nothing here: the first writes another cooling into the cell file than PyBaMM
#: gets, the second changes the logged current only.
EFFECTS: dict[str, Callable[[Effect, Any], tuple[dict, dict]]] = {
    "none": _nothing,
    "lam": _lam,
    "sei": _sei,
    "electrolyte": _electrolyte,
    "thermal": _nothing,
    "contact": _contact,
    "hysteresis": _hysteresis,
    "diffusivity": _diffusivity,
    "kinetics": _kinetics,
    "double_layer": _double_layer,
    "sensor": _nothing,
    "initial_lithium": _initial_lithium,
    "ocp_offset": _ocp_offset,
}


# ---------------------------------------------------------------------------------------------------------------
# cases
@dataclass(frozen=True)
class Case:
    """One benchmark case: ``cause`` is the catalog key that describes its effect (None: no effect), ``size`` a
    one-line description, ``profile`` its profile, ``effect`` the hidden effect, ``seed`` its noise."""

    name: str
    cause: str | None
    size: str
    profile: ProfileSpec
    effect: Effect = Effect()
    seed: int = 0

    @property
    def h_truth(self) -> float:
        """PyBaMM's heat transfer coefficient [W m⁻² K⁻¹]."""
        return float(self.effect["h_truth"]) if self.effect.kind == "thermal" else H_COOL

    @property
    def h_file(self) -> float:
        """The cell file's heat transfer coefficient [W m⁻² K⁻¹]."""
        return float(self.effect["h_file"]) if self.effect.kind == "thermal" else H_COOL

    @property
    def sensor(self) -> tuple[float, float]:
        """The current sensor's (gain, offset [A]) the log is made with."""
        if self.effect.kind != "sensor":
            return 0.0, 0.0
        return float(self.effect["gain"]), float(self.effect["offset"])

    def definition(self) -> dict[str, Any]:
        """Everything the case's data depend on (not its description)."""
        import pybamm

        d = dataclasses.asdict(self)
        d.pop("size")
        return {
            **d,
            "generator": GENERATOR,
            "pybamm": pybamm.__version__,
            "bpx_sha256": hashlib.sha256(BPX.read_bytes()).hexdigest(),
            "mesh": VAR_PTS,
            "tolerances": [RTOL, ATOL],
            "read_s": READ,
            "cutoff_V": list(V_CUTOFF),
            "ambient_K": AMBIENT_K,
            "noise": dataclasses.asdict(NOISE),
        }

    def key(self) -> str:
        """A hash of :meth:`definition`: the cached data are this case's while their key is this."""
        text = json.dumps(self.definition(), sort_keys=True, default=list)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _cases() -> dict[str, Case]:
    P = PROFILES
    nulls = [Case(f"null_{k + 1}", None, f"PyBaMM's plain DFN on profile {k + 1}", p) for k, p in enumerate(P)]
    E = Effect
    fx = [
        (
            "lam_p_7",
            "capacity_fade",
            "positive active material 7 % below the file's",
            E("lam", (("electrode", "Positive"), ("fraction", 0.07))),
        ),
        (
            "lam_p_3",
            "capacity_fade",
            "positive active material 3 % below the file's",
            E("lam", (("electrode", "Positive"), ("fraction", 0.03))),
        ),
        (
            "lam_n_5",
            "capacity_fade",
            "negative active material 5 % below the file's",
            E("lam", (("electrode", "Negative"), ("fraction", 0.05))),
        ),
        (
            "lam_n_2",
            "capacity_fade",
            "negative active material 2 % below the file's",
            E("lam", (("electrode", "Negative"), ("fraction", 0.02))),
        ),
        ("sei_fast", "capacity_fade", "reaction-limited SEI, j0 2e-5 A/m2", E("sei", (("j0", 2e-5),))),
        ("sei_slow", "capacity_fade", "reaction-limited SEI, j0 8e-6 A/m2", E("sei", (("j0", 8e-6),))),
        (
            "electrolyte_de25_k50",
            "electrolyte",
            "D_e x0.25 and kappa x0.5",
            E("electrolyte", (("D_e", 0.25), ("kappa", 0.5))),
        ),
        ("electrolyte_de40", "electrolyte", "D_e x0.4", E("electrolyte", (("D_e", 0.4), ("kappa", 1.0)))),
        (
            "thermal_cooled",
            "thermal",
            "cooled at 15 W/m2K, the file says adiabatic",
            E("thermal", (("h_truth", 15.0), ("h_file", 0.0))),
        ),
        (
            "thermal_adiabatic",
            "thermal",
            "adiabatic, the file says cooled at 10 W/m2K",
            E("thermal", (("h_truth", 0.0), ("h_file", 10.0))),
        ),
        ("contact_1p5", "contact_resistance", "contact resistance 1.5 mOhm", E("contact", (("R", 1.5e-3),))),
        ("contact_0p75", "contact_resistance", "contact resistance 0.75 mOhm", E("contact", (("R", 0.75e-3),))),
        (
            "hysteresis_10mV",
            "hysteresis",
            "negative one-state hysteresis, half-width 10 mV, decay rate 30",
            E("hysteresis", (("M", 0.010), ("gamma", 30.0))),
        ),
        (
            "hysteresis_5mV",
            "hysteresis",
            "negative one-state hysteresis, half-width 5 mV, decay rate 30",
            E("hysteresis", (("M", 0.005), ("gamma", 30.0))),
        ),
        (
            "diffusivity_n",
            "solid_diffusion",
            "D_s- x exp(3 (sto - 0.5))",
            E("diffusivity", (("electrode", "Negative"), ("b", 3.0))),
        ),
        (
            "diffusivity_p",
            "solid_diffusion",
            "D_s+ x exp(-4 (sto - 0.5))",
            E("diffusivity", (("electrode", "Positive"), ("b", -4.0))),
        ),
        (
            "kinetics_x0p3",
            "kinetics",
            "exchange-current densities x0.3 (both electrodes)",
            E("kinetics", (("factor", 0.3),)),
        ),
        (
            "kinetics_x3",
            "kinetics",
            "exchange-current densities x3 (both electrodes)",
            E("kinetics", (("factor", 3.0),)),
        ),
        (
            "double_layer_1",
            "double_layer",
            "differential surface form, 1.0 F/m2 both electrodes",
            E("double_layer", (("C_dl", 1.0),)),
        ),
        (
            "double_layer_0p2",
            "double_layer",
            "differential surface form, 0.2 F/m2 both electrodes",
            E("double_layer", (("C_dl", 0.2),)),
        ),
        (
            "sensor_gain",
            "current_sensor",
            "logged current (1 + 0.01) I",
            E("sensor", (("gain", 0.01), ("offset", 0.0))),
        ),
        ("sensor_offset", "current_sensor", "logged current I + 30 mA", E("sensor", (("gain", 0.0), ("offset", 0.03)))),
        (
            "equilibrium_lithium",
            "equilibrium",
            "negative start stoichiometry +0.012 (more lithium)",
            E("initial_lithium", (("electrode", "Negative"), ("d_sto", 0.012))),
        ),
        (
            "equilibrium_ocp",
            "equilibrium",
            "positive OCP curve +4 mV",
            E("ocp_offset", (("electrode", "Positive"), ("dU", 0.004))),
        ),
    ]
    effects = [Case(n, c, s, P[k % len(P)], e) for k, (n, c, s, e) in enumerate(fx)]
    return {c.name: dataclasses.replace(c, seed=zlib.crc32(c.name.encode())) for c in (*nulls, *effects)}


CASES: dict[str, Case] = _cases()


# ---------------------------------------------------------------------------------------------------------------
# PyBaMM
def cell_file(path: str | Path, h: float = H_COOL) -> Path:
    """The BPX cell cooled at ``h`` [W m⁻² K⁻¹] to :data:`AMBIENT_K`, written at ``path``: the file PyBaMM is fed
    and battlab diagnoses with (BPX 0.1's reader synthesises a State section of its own: it is written as BPX 1.0
    with one)."""
    data = json.loads(BPX.read_text())
    cell, electrolyte = data["Parameterisation"]["Cell"], data["Parameterisation"]["Electrolyte"]
    cell.pop("Thermal conductivity [W.m-1.K-1]", None)
    data["Header"]["BPX"] = "1.0.0"
    data["State"] = {
        "Initial conditions": {
            "Initial temperature [K]": AMBIENT_K,
            "Initial state-of-charge": 1.0,
            "Initial electrolyte concentration [mol.m-3]": electrolyte.pop("Initial concentration [mol.m-3]"),
        },
        "Thermal environment": {"Ambient temperature [K]": AMBIENT_K, "Heat transfer coefficient [W.m-2.K-1]": h},
    }
    cell.pop("Initial temperature [K]")
    cell.pop("Ambient temperature [K]")
    path = Path(path)
    path.write_text(json.dumps(data, indent=1))
    return path


def nominal_capacity() -> float:
    """The BPX cell's nominal capacity [Ah]: profiles are made in C-rates of it."""
    return float(json.loads(BPX.read_text())["Parameterisation"]["Cell"]["Nominal cell capacity [A.h]"])


@dataclass
class Truth:
    """PyBaMM's solution read at the samples (:data:`READ` after each sample's current is set): time [s], voltage
    [V], current fed [A, + = charge], cell temperature [K], discharge capacity [Ah]; the largest gap between that
    and the current's integral [Ah]; wall time [s]; lithium lost to the SEI [Ah]."""

    t: np.ndarray
    voltage: np.ndarray
    current: np.ndarray
    temperature: np.ndarray
    discharge_Ah: np.ndarray
    charge_error_Ah: float
    seconds: float
    lithium_lost_Ah: float = 0.0


def discharged(t: np.ndarray, current: np.ndarray) -> np.ndarray:
    """The zero-order-hold current's discharge capacity [Ah] at :data:`READ` after each sample (+ = charge in)."""
    q = np.concatenate([[0.0], np.cumsum(-current[:-1] * np.diff(t))])
    read = np.concatenate([np.full(t.size - 1, READ), [0.0]])
    return (q - current * read) / 3600.0


def solve(case: Case, prof: Any) -> Truth:
    """PyBaMM's DFN with lumped thermal model and ``case``'s effect on ``prof`` (from its start SOC)."""
    import pybamm

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = cell_file(Path(tmp) / "cell.json", case.h_truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pv = pybamm.ParameterValues.create_from_bpx(str(path), target_soc=prof.soc0)
    pv.update({"Lower voltage cut-off [V]": V_CUTOFF[0], "Upper voltage cut-off [V]": V_CUTOFF[1]})
    pv["Current function [A]"] = pybamm_zoh(prof.t, prof.current)
    options, values = EFFECTS[case.effect.kind](case.effect, pv)
    pv.update(values, check_already_exists=False)
    q = np.concatenate([[prof.t[0]], prof.t[1:-1] + READ, [prof.t[-1]]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # PyBaMM's notes on option changes (the hysteresis decay rate's, v25.10)
        model = pybamm.lithium_ion.DFN({"thermal": "lumped", **options})
        sim = pybamm.Simulation(
            model, parameter_values=pv, var_pts=VAR_PTS, solver=pybamm.IDAKLUSolver(rtol=RTOL, atol=ATOL)
        )
        sol = sim.solve([float(prof.t[0]), float(prof.t[-1])], t_interp=q)
    if int(np.searchsorted(q, sol.t[-1], side="right")) < prof.t.size:
        raise RuntimeError(f"{case.name}: PyBaMM stopped at {sol.t[-1]:.0f} s of {prof.t[-1]:.0f} s")
    q_pb = np.asarray(sol["Discharge capacity [A.h]"](q))
    lost = 0.0
    if case.effect.kind == "sei":
        # PyBaMM's loss variables are per electrode pair: the cell's is the number of pairs in parallel times it
        pairs = float(pv["Number of electrodes connected in parallel to make a cell"])
        lost = pairs * float(sol["Loss of capacity to negative SEI [A.h]"](q)[-1])
    return Truth(
        prof.t,
        np.asarray(sol["Voltage [V]"](q)),
        prof.current,
        np.asarray(sol["Volume-averaged cell temperature [K]"](q)),
        q_pb,
        float(np.max(np.abs(q_pb - discharged(prof.t, prof.current)))),
        time.perf_counter() - t0,
        lost,
    )


def logged(truth: Truth, seed: int, sensor: tuple[float, float] = (0.0, 0.0)) -> dict[str, np.ndarray]:
    """What the tester logs (:data:`NOISE`): voltage, current (through a sensor with (gain, offset [A])) and
    surface temperature readings."""
    rng = np.random.default_rng(seed)
    gain, offset = sensor
    v, i = truth.voltage, truth.current
    volts = np.array([NOISE.voltage(v[k], i[k], 0.0, rng) for k in range(v.size)])
    amps = np.array([NOISE.current((1.0 + gain) * x + offset, rng) for x in i])
    temps = np.array([NOISE.temperature(x, rng) for x in truth.temperature])
    return {"voltage": volts, "current": amps, "temperature": temps}


def check_charge(case: Case, truth: Truth, logged_current: np.ndarray) -> float:
    """The largest gap [Ah] between PyBaMM's discharge capacity and the integral of the logged current (the sensor's
    error taken out); raises when it, or the gap to the current PyBaMM was fed, is above its tolerance."""
    if truth.charge_error_Ah > CHARGE_TOL_SOLVER:
        raise RuntimeError(
            f"{case.name}: PyBaMM's discharge capacity is {truth.charge_error_Ah:.2e} Ah from the integral of the "
            f"current it was fed (tolerance {CHARGE_TOL_SOLVER:g} Ah): the current was not integrated exactly"
        )
    gain, offset = case.sensor
    gap = float(np.max(np.abs(truth.discharge_Ah - discharged(truth.t, (logged_current - offset) / (1.0 + gain)))))
    if gap > CHARGE_TOL_LOG:
        raise RuntimeError(
            f"{case.name}: PyBaMM's discharge capacity is {gap:.2e} Ah from the integral of the logged current "
            f"(tolerance {CHARGE_TOL_LOG:g} Ah)"
        )
    return gap


# ---------------------------------------------------------------------------------------------------------------
# the cache
def paths(folder: str | Path, name: str) -> dict[str, Path]:
    """A case's files in the cache ``folder``."""
    f = Path(folder)
    return {
        "csv": f / f"{name}.bdf.csv",
        "cell": f / f"{name}.bpx.json",
        "truth": f / f"{name}.truth.npz",
        "case": f / f"{name}.case.json",
    }


def cached(case: Case, folder: str | Path) -> dict[str, Any] | None:
    """The generation record of ``case`` in ``folder`` when every file is there and made from its definition."""
    p = paths(folder, case.name)
    if not all(x.is_file() for x in p.values()):
        return None
    record = json.loads(p["case"].read_text())
    return record if record.get("key") == case.key() else None


def make_case(case: Case, folder: str | Path, force: bool = False) -> dict[str, Any]:
    """Make ``case``'s files in ``folder`` (see the module docstring) unless they are cached; returns its record.
    The record is written last, so an interrupted case is made again."""
    from battlab.io.bdf import read_bdf_csv, write_bdf_csv
    from battlab.io.data import AMBIENT, CURRENT, SURFACE, TIME, VOLTAGE, LoggedData

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if not force and (record := cached(case, folder)) is not None:
        return {**record, "made": False}
    p = paths(folder, case.name)
    p["case"].unlink(missing_ok=True)
    prof = make_profile(nominal_capacity(), case.profile)
    truth = solve(case, prof)
    m = logged(truth, case.seed, case.sensor)
    cols = {
        TIME: truth.t,
        VOLTAGE: m["voltage"],
        CURRENT: m["current"],
        AMBIENT: np.full(truth.t.size, AMBIENT_K - 273.15),
        SURFACE: m["temperature"] - 273.15,
    }
    meta = {"soc0": prof.soc0, "source": f"PyBaMM DFN (benchmarks/pybamm_effects.py, case {case.name})"}
    write_bdf_csv(LoggedData(case.name, cols, meta), p["csv"])
    gap = check_charge(case, truth, read_bdf_csv(p["csv"]).columns[CURRENT])
    cell_file(p["cell"], case.h_file)
    np.savez_compressed(
        p["truth"], t=truth.t, voltage=truth.voltage, current=truth.current, temperature=truth.temperature
    )
    record = {
        "name": case.name,
        "cause": case.cause,
        "size": case.size,
        "key": case.key(),
        "definition": case.definition(),
        "pybamm_seconds": truth.seconds,
        "charge_error_solver_Ah": truth.charge_error_Ah,
        "charge_error_log_Ah": gap,
        "lithium_lost_Ah": truth.lithium_lost_Ah,
        "voltage_range_V": [float(truth.voltage.min()), float(truth.voltage.max())],
        "temperature_rise_K": float(truth.temperature.max() - AMBIENT_K),
    }
    p["case"].write_text(json.dumps(record, indent=1, default=list))
    return {**record, "made": True}


def _make_one(name: str, folder: str, force: bool, nice: int) -> dict[str, Any]:
    if nice:
        os.nice(nice)
    try:
        return make_case(CASES[name], folder, force)
    except Exception as exc:  # a refused or failed case is reported and the others go on
        return {"name": name, "error": f"{type(exc).__name__}: {exc}"}


def _say(r: dict[str, Any]) -> None:
    if "error" in r:
        print(f"{r['name']:<22} REFUSED  {r['error']}", flush=True)
        return
    how = f"made in {r['pybamm_seconds']:.0f} s" if r["made"] else "cached"
    extra = f", lithium lost {1e3 * r['lithium_lost_Ah']:.0f} mAh" if r["lithium_lost_Ah"] else ""
    print(
        f"{r['name']:<22} {how:<16} charge gap solver {r['charge_error_solver_Ah']:.1e} Ah, log "
        f"{r['charge_error_log_Ah']:.1e} Ah; V {r['voltage_range_V'][0]:.3f}-{r['voltage_range_V'][1]:.3f}, "
        f"dT {r['temperature_rise_K']:.1f} K{extra}",
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="the cache folder (made if missing)")
    ap.add_argument("--cases", default=None, help="comma-separated case names (default: all; --list shows them)")
    ap.add_argument("--list", action="store_true", help="list the cases and whether each is cached, then stop")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1; the machine is shared)")
    ap.add_argument("--nice", type=int, default=10, help="lower the workers' priority by this (default 10)")
    ap.add_argument("--force", action="store_true", help="make the cases again even when cached")
    args = ap.parse_args(argv)
    names = args.cases.split(",") if args.cases else list(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        print(f"unknown case(s) {unknown}; expected some of {', '.join(CASES)}", file=sys.stderr)
        return 2
    if args.list:
        for n in names:
            c = CASES[n]
            state = "cached" if cached(c, args.data) else "missing"
            print(f"{n:<22} {state:<8} {c.cause!s:<18} profile {c.profile.seed}  {c.size}")
        return 0
    results = []
    if args.workers <= 1:
        if args.nice:
            os.nice(args.nice)
        for n in names:
            results.append(_make_one(n, args.data, args.force, 0))
            _say(results[-1])
    else:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(args.workers, mp_context=ctx) as pool:
            futures = [pool.submit(_make_one, n, args.data, args.force, args.nice) for n in names]
            for f in as_completed(futures):
                results.append(f.result())
                _say(results[-1])
    refused = [r["name"] for r in results if "error" in r]
    print(
        f"{len(results) - len(refused)} of {len(results)} cases in {args.data}"
        + (f"; refused {refused}" if refused else "")
    )
    return 1 if refused else 0


if __name__ == "__main__":
    sys.exit(main())
