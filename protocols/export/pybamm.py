"""PyBaMM export: a Python module ``<name>.py`` exposing ``experiment() -> pybamm.Experiment``.

Conventions:

* **Sign**: PyBaMM counts discharge current as positive, battlab counts charge as positive; every current in
  the module is the negative of the protocol's (the only sign flip in this package).
* Steps map to ``pybamm.step.rest`` / ``current`` / ``voltage`` with ``duration`` (a time end) and
  ``termination`` strings (``"> 4.2 V"``, ``"< 2.5 V"``, ``"0.054 A"`` = |I| below 0.054 A). A CCCV step is a
  current step terminated at the voltage followed by a voltage step (see
  :func:`protocols.export.program.split_cccv`); a CV step keeps its direction (``direction="charge"``). A
  capacity end of a CC step becomes the equivalent duration (|Q| / |I|) and is kept in the step description.
* A sampled profile is a drive cycle: ``pybamm.step.current(array)`` with the array read from
  ``<name>_step<k>.csv`` beside the module (time [s], current [A] in PyBaMM's sign). PyBaMM interpolates a
  drive cycle linearly, so each zero-order-hold segment is written as two points, its start and 1 ms before
  its end; the current therefore ramps to the next value within 1 ms (a charge error of at most
  |dI| x 0.5 ms per edge, below 1 uAh).
* Safety limits are not experiment fields in PyBaMM: the module's ``parameter_updates()`` returns the voltage
  cut-offs (``"Lower voltage cut-off [V]"``, ``"Upper voltage cut-off [V]"``) to apply to the parameter set,
  and ``SAFETY`` lists all four limits.

Refused: a rest or CV step without a time end, capacity ends of CV/CCCV steps, ``current >=`` ends, and
segments shorter than 2 ms. No segment limit. PyBaMM is imported only by the generated module (and by
:func:`read`), never by this package.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np

from protocols.directions import Direction
from protocols.errors import InputError
from protocols.export.base import ExportResult, FormatRules, ReadBack, check_times, profile_plan, where
from protocols.export.program import Canonical, Hold, expand, merge_holds, split_cccv, time_only
from protocols.protocol import (
    Comparison,
    ConstantCurrent,
    ConstantVoltage,
    EndCondition,
    ProfileStep,
    Protocol,
    Quantity,
    Rest,
    Step,
)

RAMP_S = 1e-3
RULES = FormatRules(
    label="PyBaMM",
    time_resolution_s=1e-6,
    min_duration_s=2 * RAMP_S,
    current_resolution_a=1e-12,
    max_steps=None,
    loops=False,
)


def module_name(name: str) -> str:
    """A valid Python module name made from ``name``."""
    s = re.sub(r"\W+", "_", name).strip("_") or "experiment"
    return s if s[0].isalpha() else f"exp_{s}"


def _num(x: float) -> str:
    return repr(float(x) + 0.0)


def _termination(e: EndCondition, w: str) -> str:
    if e.quantity is Quantity.VOLTAGE:
        return f"{'>' if e.op is Comparison.GE else '<'} {_num(e.value)} V"
    if e.quantity is Quantity.CURRENT and e.op is Comparison.LE:
        return f"{_num(e.value)} A"
    raise InputError(f"{w}: PyBaMM cannot end a step on '{e}'")


def drive_cycle_array(holds: list[Hold]) -> np.ndarray:
    """Two-column array (time [s], PyBaMM current [A]) that PyBaMM's interpolation plays as ``holds``."""
    rows = []
    t = 0.0
    for h in holds:
        rows.append((t, -h.current + 0.0))
        rows.append((t + h.duration - RAMP_S, -h.current + 0.0))
        t += h.duration
    rows.append((t, -holds[-1].current + 0.0))
    return np.array(rows)


def write(protocol: Protocol, out_dir: Path, *, name: str | None = None, rules: FormatRules = RULES) -> ExportResult:
    """Write ``<name>.py`` and one ``<name>_step<k>.csv`` per profile step into ``out_dir``."""
    protocol.check()
    check_times(protocol, rules)
    proto = split_cccv(protocol)
    mod = module_name(name or protocol.name)
    out_dir = Path(out_dir)
    files: list[Path] = []
    tables: list[tuple[Path, np.ndarray]] = []
    calls: list[str] = []
    for k, s in enumerate(proto.steps, start=1):
        w = where(proto, k, s)
        if isinstance(s, ProfileStep):
            holds = expand(profile_plan(proto, k, s, rules))
            csv = out_dir / f"{mod}_step{k}.csv"
            tables.append((csv, drive_cycle_array(holds)))
            files.append(csv)
            desc = f"profile {s.profile.id}" if s.profile.id is not None else "profile"
            calls.append(f'pybamm.step.current(_drive_cycle("{csv.name}"), description={desc!r})')
            continue
        time = next((e.value for e in s.ends if e.quantity is Quantity.TIME), None)
        cap = next((e.value for e in s.ends if e.quantity is Quantity.CAPACITY), None)
        terms = [_termination(e, w) for e in s.ends if e.quantity in (Quantity.VOLTAGE, Quantity.CURRENT)]
        args = []
        desc = s.kind.value
        if isinstance(s, ConstantCurrent):
            if cap is not None:
                t_cap = cap * 3600.0 / abs(s.current)
                time = t_cap if time is None else min(time, t_cap)
                desc += f": capacity >= {cap!r}"
                if any(e.quantity is Quantity.TIME for e in s.ends):
                    desc += f"; time >= {next(e.value for e in s.ends if e.quantity is Quantity.TIME)!r}"
            head = f"pybamm.step.current({_num(-s.current)}"
        elif isinstance(s, ConstantVoltage):
            if cap is not None:
                raise InputError(f"{w}: PyBaMM cannot end a voltage step on capacity")
            head = f'pybamm.step.voltage({_num(s.voltage)}, direction="{s.direction.value}"'
        else:
            assert isinstance(s, Rest)
            head = "pybamm.step.rest("
        if isinstance(s, Rest | ConstantVoltage) and time is None:
            raise InputError(f"{w}: PyBaMM needs a time end on this step (add 'time >= ...')")
        if time is not None:
            args.append(f"duration={_num(time)}")
        if terms:
            args.append(f"termination={terms!r}")
        args.append(f"description={desc!r}")
        sep = "" if head.endswith("(") else ", "
        calls.append(head + sep + ", ".join(args) + ")")
    lim = protocol.limits
    body = "\n".join(f"            {c}," for c in calls)
    text = f'''"""PyBaMM experiment {protocol.name!r}, exported by battlab protocols.

Sign: PyBaMM counts discharge current as positive (battlab: charge), so every current here is already
negated. Sampled profiles are drive cycles read from the CSV files beside this module (time [s], current [A]
in PyBaMM's sign; each hold ends with a 1 ms linear ramp to the next value).
Voltage limits are parameters in PyBaMM: apply ``parameter_updates()`` to your parameter values.
"""

from pathlib import Path

import numpy as np
import pybamm

HERE = Path(__file__).resolve().parent
SAFETY = {{
    "voltage_min": {_num(lim.voltage_min)},
    "voltage_max": {_num(lim.voltage_max)},
    "current_max": {_num(lim.current_max)},
    "temperature_max": {_num(lim.temperature_max)},
}}


def _drive_cycle(name: str) -> np.ndarray:
    return np.loadtxt(HERE / name, delimiter=",", skiprows=1)


def parameter_updates() -> dict:
    """Voltage cut-offs of the protocol's safety limits, as PyBaMM parameters."""
    return {{
        "Lower voltage cut-off [V]": SAFETY["voltage_min"],
        "Upper voltage cut-off [V]": SAFETY["voltage_max"],
    }}


def experiment() -> pybamm.Experiment:
    """The protocol as a pybamm.Experiment (PyBaMM sign: positive current = discharge)."""
    return pybamm.Experiment(
        [
{body}
        ]
    )
'''
    path = out_dir / f"{mod}.py"
    for csv, table in tables:  # written only once every step has been accepted
        np.savetxt(csv, table, delimiter=",", fmt="%.17g", header="t_s,current_A", comments="")
    path.write_text(text, encoding="utf-8")
    return ExportResult((path, *files))


# --- re-import (needs pybamm; used by the tests) ---------------------------------------------------------


def load_module(path: str | Path):  # noqa: ANN201 - a module object
    """Import a generated module from its file."""
    path = Path(path)
    name = f"_protocols_export_{abs(hash(str(path.resolve())))}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise InputError(f"{path}: cannot import")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _holds_from_array(arr: np.ndarray) -> list[Hold]:
    t, i = arr[:, 0], arr[:, 1]
    starts = t[0:-1:2]
    values = -i[0:-1:2] + 0.0
    ends = np.concatenate([starts[1:], [t[-1]]])
    return [Hold(float(e - s), float(v)) for s, e, v in zip(starts, ends, values, strict=True)]


def read(path: str | Path) -> ReadBack:
    """Re-import a generated module by running ``experiment()`` in PyBaMM and reading its steps."""
    module = load_module(path)
    exp = module.experiment()
    items: list[Canonical] = []
    for st in exp.steps:
        kind = type(st).__name__
        if st.is_drive_cycle:
            items.extend(_holds_from_array(np.asarray(st.input_value, dtype=float)))
            continue
        ends: list[EndCondition] = []
        desc = st.description or ""
        for term in st.termination:
            tname = type(term).__name__
            if tname == "VoltageTermination":
                ends.append(
                    EndCondition(Quantity.VOLTAGE, Comparison.GE if term.operator == ">" else Comparison.LE, term.value)
                )
            elif tname == "CurrentTermination":
                ends.append(EndCondition(Quantity.CURRENT, Comparison.LE, term.value))
        m = re.search(r"capacity >= ([0-9.eE+-]+)", desc)
        if m:
            ends.append(EndCondition(Quantity.CAPACITY, Comparison.GE, float(m.group(1))))
            mt = re.search(r"time >= ([0-9.eE+-]+)", desc)
            if mt:
                ends.append(EndCondition(Quantity.TIME, Comparison.GE, float(mt.group(1))))
        elif not st.uses_default_duration:
            ends.append(EndCondition(Quantity.TIME, Comparison.GE, float(st.duration)))
        if kind == "Rest":
            step: Step = Rest(tuple(ends))
        elif kind == "Current":
            step = ConstantCurrent(-float(st.value) + 0.0, tuple(ends))
        elif kind == "Voltage":
            step = ConstantVoltage(float(st.value), tuple(ends), Direction(st.direction))
        else:
            raise InputError(f"{path}: PyBaMM step {kind} is not one this exporter writes")
        d = time_only(step)
        items.append(Hold(d, step.current if isinstance(step, ConstantCurrent) else 0.0) if d is not None else step)
    s = module.SAFETY
    return ReadBack(merge_holds(items), s["voltage_min"], s["voltage_max"], s["current_max"], s["temperature_max"])
