"""Neware BTS step-file export (``<name>.xml``).

Conventions (learned from aurora-unicycler's Neware writer, tested there on BTS 8.0):

* XML ``root/config`` (``type="Step File"``, ``version="17"``) with ``Head_Info``, the whole-test protection
  ``Whole_Prt/Protect`` and record interval ``Whole_Prt/Record``, and ``Step_Info`` holding ``Step<n>``
  elements (``Step_ID`` n, 1-based) with their values under ``Limit/Main``.
* Units: current ``Curr`` in mA (magnitude; the sign is in the step type), voltage ``Volt``/``Stop_Volt`` in
  0.1 mV (V x 10000), time ``Time`` in ms, capacity ``Cap`` in mAs (mAh x 3600).
* Step types: 1 CC charge, 2 CC discharge, 3 CCCV charge, 19 CCCV discharge (``Curr``, ``Volt``, ``Stop_Curr``
  = the |I| taper), 4 rest, 5 loop (``Other/Start_Step`` = first step id of the body, ``Other/Cycle_Count``
  = number of passes), 6 end. A CC step's voltage end is ``Stop_Volt`` (reached from below when charging,
  from above when discharging).
* A sampled profile becomes one CC/rest step per zero-order-hold segment ending on ``Time``; runs that
  repeat become a loop step.
* Protection: ``Volt`` ``Upper``/``Lower`` and ``Curr`` ``Upper`` (the safety limits); the temperature limit
  has no field here and is reported as a note.

What this mapping cannot express is refused with the step named: a pure CV step (no known step type; use
CCCV), a rest ending on voltage, a CC step ending on a voltage on the wrong side, a current end other than
``current <=``, and more than one end of the same kind. Resolution and limits (assumptions, not checked
against Neware's documentation): times in whole ms and steps of at least 100 ms; currents to 1 nA (mA with 6
decimals); a step file holds at most 1000 steps.
"""

from __future__ import annotations

import uuid
import xml.etree.ElementTree as ET
from datetime import datetime
from pathlib import Path
from xml.dom import minidom

from protocols.errors import InputError
from protocols.export.base import (
    ExportResult,
    FormatRules,
    ReadBack,
    check_step_count,
    check_times,
    profile_plan,
    safe_name,
    where,
)
from protocols.export.program import Canonical, Hold, Repeat, merge_holds, time_only
from protocols.protocol import (
    CCCV,
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

RULES = FormatRules(
    label="Neware BTS",
    time_resolution_s=0.001,
    min_duration_s=0.1,
    current_resolution_a=1e-9,
    max_steps=1000,
    loops=True,
)
CC_CHARGE, CC_DISCHARGE, CCCV_CHARGE, REST, LOOP, END, CCCV_DISCHARGE = "1", "2", "3", "4", "5", "6", "19"


def _sub(parent: ET.Element, tag: str, value: float | str) -> None:
    ET.SubElement(parent, tag, Value=value if isinstance(value, str) else f"{value:f}")


def _step_el(n: int, typ: str) -> tuple[ET.Element, ET.Element]:
    el = ET.Element(f"Step{n}", Step_ID=str(n), Step_Type=typ)
    return el, ET.SubElement(ET.SubElement(el, "Limit"), "Main")


def _ends(main: ET.Element, ends: tuple[EndCondition, ...], s: Step, where_: str) -> None:
    seen: set[Quantity] = set()
    for e in ends:
        if e.quantity in seen:
            raise InputError(f"{where_}: Neware takes one {e.quantity.value} end per step")
        seen.add(e.quantity)
        if e.quantity is Quantity.TIME:
            _sub(main, "Time", e.value * 1000)
        elif e.quantity is Quantity.VOLTAGE:
            if isinstance(s, Rest):
                raise InputError(f"{where_}: a Neware rest step cannot end on voltage")
            charging = getattr(s, "current", 0.0) > 0
            if (e.op is Comparison.GE) != charging:
                raise InputError(
                    f"{where_}: Neware stops a {'charge' if charging else 'discharge'} step on voltage "
                    f"{'>=' if charging else '<='} only; '{e}' is on the other side"
                )
            _sub(main, "Stop_Volt", e.value * 10000)
        elif e.quantity is Quantity.CURRENT:
            if e.op is not Comparison.LE:
                raise InputError(f"{where_}: Neware ends on current only as 'current <= x'")
            _sub(main, "Stop_Curr", e.value * 1000)
        else:
            _sub(main, "Cap", e.value * 1000 * 3600)


def _hold(n: int, h: Hold) -> ET.Element:
    if h.current == 0:
        el, main = _step_el(n, REST)
    else:
        el, main = _step_el(n, CC_CHARGE if h.current > 0 else CC_DISCHARGE)
        _sub(main, "Curr", abs(h.current) * 1000)
    _sub(main, "Time", h.duration * 1000)
    return el


def write(
    protocol: Protocol,
    out_dir: Path,
    *,
    name: str | None = None,
    rules: FormatRules = RULES,
    created: datetime | None = None,
) -> ExportResult:
    """Write ``<name>.xml`` into ``out_dir`` (``created`` stamps the file; default now)."""
    protocol.check()
    check_times(protocol, rules)
    steps: list[ET.Element] = []
    for k, s in enumerate(protocol.steps, start=1):
        w = where(protocol, k, s)
        if isinstance(s, ProfileStep):
            for it in profile_plan(protocol, k, s, rules):
                if isinstance(it, Hold):
                    steps.append(_hold(len(steps) + 1, it))
                    continue
                first = len(steps) + 1
                for h in it.body:
                    steps.append(_hold(len(steps) + 1, h))
                el, _ = _step_el(len(steps) + 1, LOOP)
                el.remove(el.find("Limit"))  # type: ignore[arg-type]
                other = ET.SubElement(ET.SubElement(el, "Limit"), "Other")
                _sub(other, "Start_Step", str(first))
                _sub(other, "Cycle_Count", str(it.count))
                steps.append(el)
            continue
        n = len(steps) + 1
        if isinstance(s, ConstantVoltage):
            raise InputError(f"{w}: Neware step files have no pure CV step in this exporter; use a cccv step")
        if isinstance(s, Rest):
            el, main = _step_el(n, REST)
        elif isinstance(s, ConstantCurrent):
            el, main = _step_el(n, CC_CHARGE if s.current > 0 else CC_DISCHARGE)
            _sub(main, "Curr", abs(s.current) * 1000)
        else:
            assert isinstance(s, CCCV)
            el, main = _step_el(n, CCCV_CHARGE if s.current > 0 else CCCV_DISCHARGE)
            _sub(main, "Curr", abs(s.current) * 1000)
            _sub(main, "Volt", s.voltage * 10000)
        _ends(main, s.ends, s, w)
        steps.append(el)
    check_step_count(protocol, len(steps) + 1, rules)
    lim = protocol.limits
    stamp = created or datetime.now()
    root = ET.Element("root")
    config = ET.SubElement(
        root,
        "config",
        type="Step File",
        version="17",
        client_version="BTS Client 8.0.0.478(2024.06.24)(R3)",
        date=stamp.strftime("%Y%m%d%H%M%S"),
        Guid=str(uuid.uuid5(uuid.NAMESPACE_URL, f"battlab-protocols/{protocol.name}/{stamp.isoformat()}")),
    )
    head = ET.SubElement(config, "Head_Info")
    _sub(head, "Operate", "66")
    _sub(head, "Scale", "1")
    ET.SubElement(head, "Start_Step", Value="1", Hide_Ctrl_Step="0")
    _sub(head, "Creator", "battlab protocols")
    _sub(head, "Remark", protocol.name)
    _sub(head, "RateType", "103")
    _sub(head, "MultCap", protocol.capacity_ah * 1000 * 3600)
    whole = ET.SubElement(config, "Whole_Prt")
    protect = ET.SubElement(ET.SubElement(whole, "Protect"), "Main")
    volt = ET.SubElement(protect, "Volt")
    _sub(volt, "Upper", lim.voltage_max * 10000)
    _sub(volt, "Lower", lim.voltage_min * 10000)
    curr = ET.SubElement(protect, "Curr")
    _sub(curr, "Upper", lim.current_max * 1000)
    record = ET.SubElement(ET.SubElement(whole, "Record"), "Main")
    _sub(record, "Time", 1000.0)
    info = ET.SubElement(config, "Step_Info", Num=str(len(steps) + 1))
    for el in steps:
        info.append(el)
    ET.SubElement(info, f"Step{len(steps) + 1}", Step_ID=str(len(steps) + 1), Step_Type=END)
    smbus = ET.SubElement(config, "SMBUS")
    ET.SubElement(smbus, "SMBUS_Info", Num="0", AdjacentInterval="0")
    text = minidom.parseString(ET.tostring(root)).toprettyxml(indent="  ")  # noqa: S318
    path = Path(out_dir) / f"{safe_name(name or protocol.name)}.xml"
    path.write_text(text, encoding="utf-8")
    notes = (f"Neware: the temperature limit {lim.temperature_max - 273.15:g} degC is not in the step file",)
    return ExportResult((path,), notes)


# --- re-import ---------------------------------------------------------------------------------------------


def _val(main: ET.Element | None, tag: str) -> float | None:
    if main is None:
        return None
    el = main.find(tag)
    return float(el.attrib["Value"]) if el is not None else None


def read(path: str | Path) -> ReadBack:
    """Re-import a step file written by :func:`write` by playing its loops."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(f"{path}: not valid XML: {exc}") from None
    info = root.find("./config/Step_Info")
    if info is None:
        raise InputError(f"{path}: no Step_Info")
    steps = sorted(info, key=lambda el: int(el.attrib["Step_ID"]))
    items: list[Canonical] = []
    passes = [0] * len(steps)
    pc, guard = 0, 0
    while pc < len(steps):
        guard += 1
        if guard > 10_000_000:
            raise InputError(f"{path}: loops do not terminate")
        el = steps[pc]
        typ = el.attrib["Step_Type"]
        if typ == END:
            break
        if typ == LOOP:
            other = el.find("./Limit/Other")
            passes[pc] += 1
            if passes[pc] < int(_val(other, "Cycle_Count") or 1):
                pc = int(_val(other, "Start_Step") or 1) - 1
            else:
                passes[pc] = 0
                pc += 1
            continue
        items.append(_read_step(path, el))
        pc += 1
    protect = root.find("./config/Whole_Prt/Protect/Main")
    vmax = _val(protect.find("Volt") if protect is not None else None, "Upper")
    vmin = _val(protect.find("Volt") if protect is not None else None, "Lower")
    imax = _val(protect.find("Curr") if protect is not None else None, "Upper")
    return ReadBack(
        merge_holds(items),
        voltage_min=None if vmin is None else vmin / 10000,
        voltage_max=None if vmax is None else vmax / 10000,
        current_max=None if imax is None else imax / 1000,
    )


def _read_step(path: Path, el: ET.Element) -> Canonical:
    typ = el.attrib["Step_Type"]
    main = el.find("./Limit/Main")
    ends = []
    t, v, i_stop, cap = (_val(main, tag) for tag in ("Time", "Stop_Volt", "Stop_Curr", "Cap"))
    charging = typ in (CC_CHARGE, CCCV_CHARGE)
    if t is not None:
        ends.append(EndCondition(Quantity.TIME, Comparison.GE, t / 1000))
    if v is not None:
        ends.append(EndCondition(Quantity.VOLTAGE, Comparison.GE if charging else Comparison.LE, v / 10000))
    if i_stop is not None:
        ends.append(EndCondition(Quantity.CURRENT, Comparison.LE, i_stop / 1000))
    if cap is not None:
        ends.append(EndCondition(Quantity.CAPACITY, Comparison.GE, cap / 1000 / 3600))
    curr = _val(main, "Curr")
    sign = 1.0 if charging else -1.0
    if typ == REST:
        step: Step = Rest(tuple(ends))
    elif typ in (CC_CHARGE, CC_DISCHARGE):
        step = ConstantCurrent(sign * (curr or 0.0) / 1000, tuple(ends))
    elif typ in (CCCV_CHARGE, CCCV_DISCHARGE):
        step = CCCV(sign * (curr or 0.0) / 1000, (_val(main, "Volt") or 0.0) / 10000, tuple(ends))
    else:
        raise InputError(f"{path}: step type {typ} is not one this exporter writes")
    d = time_only(step)
    if d is not None:
        return Hold(d, step.current if isinstance(step, ConstantCurrent) else 0.0)
    return step


__all__ = ["RULES", "Repeat", "read", "write"]
