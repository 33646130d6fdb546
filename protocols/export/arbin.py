"""Arbin MITS Pro schedule export (``<name>.sdu``).

Conventions (learned from the schedule templates and the Maccor-to-Arbin converter of TRI's BEEP):

* INI-like text (latin-1, CRLF): ``[Schedule]`` holds the global settings, ``[Schedule_Step<k>]`` each step
  (0-based) and ``[Schedule_Step<k>_Limit<j>]`` its limits (end conditions and logging rules).
* Current is signed, positive = charge (Arbin's convention equals battlab's), in A: ``Current(A)`` steps
  carry it in ``m_szCtrlValue``; ``CCCV`` steps carry the current and, in ``m_szExtCtrlValue1``, the voltage;
  ``Voltage(V)`` steps the voltage (the CV direction is kept in the step label); ``Rest`` steps nothing.
* Ends become step limits (``m_bStepLimit=1``, goto ``Next Step``): ``PV_CHAN_Step_Time >=`` [s],
  ``PV_CHAN_Voltage >=``/``<=`` [V], the CV current (``PV_CHAN_CV_Stage_Current`` in CCCV steps,
  ``PV_CHAN_Current`` in CV steps; ``<= I`` when charging, ``>= -I`` when discharging), and the step's
  ``PV_CHAN_Charge_Capacity``/``PV_CHAN_Discharge_Capacity >=`` [Ah]. Every step also logs every 1 s
  (``DV_Time``, ``m_bStepLimit=0``).
* A sampled profile becomes one ``Current(A)``/``Rest`` step per zero-order-hold segment ending on
  ``PV_CHAN_Step_Time``; runs that repeat become a loop on test counter 1 (as BEEP converts Maccor loops): a
  ``Set Variable(s)`` step that resets TC1 (``m_szCtrlValue=65536``), the body, and a ``Set Variable(s)`` step
  that increments TC1 (``m_szExtCtrlValue1=2``) and goes back to the body while ``TC_Counter1 <`` the count.
* Safety: ``m_VoltageSafetyScope`` and ``m_CurrentSafetyScope`` (``min^max``), and the auxiliary temperature
  scope in degC (``m_AuxTempSafetyScope``, channel 1 enabled).

Resolution and limits (assumptions, not checked against Arbin's documentation): times are written to 1 ms and
a step lasts at least 10 ms; currents to 1 uA; a schedule holds at most 1000 steps (raise ``max_steps`` if
your MITS Pro version takes more). Arbin's "Current Simulation" step for drive cycles is not used: its file
format is not public in the open generators this exporter learned from.
"""

from __future__ import annotations

import re
from pathlib import Path

from protocols.directions import Direction
from protocols.errors import InputError
from protocols.export.base import (
    ExportResult,
    FormatRules,
    ReadBack,
    check_step_count,
    check_times,
    fmt_num,
    profile_plan,
    safe_name,
)
from protocols.export.program import Canonical, Hold, Item, Repeat, merge_holds, time_only
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
    label="Arbin",
    time_resolution_s=0.001,
    min_duration_s=0.01,
    current_resolution_a=1e-6,
    max_steps=1000,
    loops=True,
)
RESET_TC1 = 2**16
INCREMENT_TC1 = 2

_STEP_FIELDS = (
    "m_uLimitNum",
    "m_szLabel",
    "m_szStepCtrlType",
    "m_szCurrentRange",
    "m_szVoltageRange",
    "m_szCtrlValue",
    "m_szExtCtrlValue1",
    "m_szExtCtrlValue2",
    "m_szExtDef",
    "m_uStepCtrlTypeExtFlag",
    "m_szAddIn",
    "m_bSampleClockStretch",
    "m_szUnitType",
    "m_szExUnitType1",
    "m_bSynchronizedStart",
    "m_bAutoPidTips",
    "m_nExtra1",
    "m_szExtDef1",
    "m_bBurstModeEnable",
)


def _limit(step_limit: bool, left: str, sign: str, right: str, goto: str = "Next Step") -> dict[str, str]:
    return {
        "m_bStepLimit": "1" if step_limit else "0",
        "m_bLogDataLimit": "1",
        "m_szGotoStep": goto,
        "Equation0_szLeft": left,
        "Equation0_szCompareSign": sign,
        "Equation0_szRight": right,
        "Equation1_szLeft": "",
        "Equation1_szCompareSign": "",
        "Equation1_szRight": "",
        "Equation2_szLeft": "",
        "Equation2_szCompareSign": "",
        "Equation2_szRight": "",
    }


_LOG = _limit(False, "DV_Time", ">=", "1")


class _Step:
    def __init__(self, label: str, ctrl: str, value: str = "", ext1: str = "", ext2: str = "") -> None:
        self.fields = dict.fromkeys(_STEP_FIELDS, "")
        self.fields.update(
            {
                "m_szLabel": label,
                "m_szStepCtrlType": ctrl,
                "m_szCurrentRange": "Range1",
                "m_szVoltageRange": "High",
                "m_szCtrlValue": value,
                "m_szExtCtrlValue1": ext1,
                "m_szExtCtrlValue2": ext2,
                "m_uStepCtrlTypeExtFlag": "0",
                "m_bSampleClockStretch": "0",
                "m_bSynchronizedStart": "0",
                "m_bAutoPidTips": "0",
                "m_nExtra1": "0",
                "m_bBurstModeEnable": "0",
            }
        )
        self.limits: list[dict[str, str]] = []


def _end_limit(e: EndCondition, s: Step) -> dict[str, str]:
    if e.quantity is Quantity.TIME:
        return _limit(True, "PV_CHAN_Step_Time", ">=", fmt_num(e.value, 3))
    if e.quantity is Quantity.VOLTAGE:
        return _limit(True, "PV_CHAN_Voltage", e.op.value, fmt_num(e.value, 6))
    charging = _charging(s)
    if e.quantity is Quantity.CURRENT:
        left = "PV_CHAN_CV_Stage_Current" if isinstance(s, CCCV) else "PV_CHAN_Current"
        if charging:
            return _limit(True, left, e.op.value, fmt_num(e.value, 6))
        flipped = ">=" if e.op is Comparison.LE else "<="
        return _limit(True, left, flipped, fmt_num(-e.value, 6))
    left = "PV_CHAN_Charge_Capacity" if charging else "PV_CHAN_Discharge_Capacity"
    return _limit(True, left, ">=", fmt_num(e.value, 6))


def _charging(s: Step) -> bool:
    if isinstance(s, ConstantVoltage):
        return s.direction is Direction.CHARGE
    return getattr(s, "current", 0.0) > 0


def _hold_step(n: int, h: Hold) -> _Step:
    st = _Step(f"{n}-hold", "Rest") if h.current == 0 else _Step(f"{n}-hold", "Current(A)", fmt_num(h.current, 6))
    st.limits = [_limit(True, "PV_CHAN_Step_Time", ">=", fmt_num(h.duration, 3)), _LOG]
    return st


def _profile_steps(items: tuple[Item, ...], start: int) -> list[_Step]:
    out: list[_Step] = []
    for it in items:
        n = start + len(out)
        if isinstance(it, Hold):
            out.append(_hold_step(n, it))
            continue
        reset = _Step(f"{n}-loop start", "Set Variable(s)", str(RESET_TC1), "0", "0")
        reset.limits = [_limit(True, "PV_CHAN_Step_Time", ">", "0")]
        out.append(reset)
        body_label = f"{n + 1}-hold"
        for h in it.body:
            out.append(_hold_step(start + len(out), h))
        n_end = start + len(out)
        inc = _Step(f"{n_end}-loop x{it.count}", "Set Variable(s)", "0", str(INCREMENT_TC1), "0")
        inc.limits = [
            _limit(True, "TC_Counter1", "<", str(it.count), goto=body_label),
            _limit(True, "TC_Counter1", ">=", str(it.count)),
        ]
        out.append(inc)
    return out


def write(protocol: Protocol, out_dir: Path, *, name: str | None = None, rules: FormatRules = RULES) -> ExportResult:
    """Write ``<name>.sdu`` into ``out_dir``."""
    protocol.check()
    check_times(protocol, rules)
    steps: list[_Step] = []
    for k, s in enumerate(protocol.steps, start=1):
        n = len(steps) + 1
        if isinstance(s, ProfileStep):
            steps += _profile_steps(profile_plan(protocol, k, s, rules), n)
            continue
        if isinstance(s, Rest):
            st = _Step(f"{n}-rest", "Rest")
        elif isinstance(s, ConstantCurrent):
            st = _Step(f"{n}-cc", "Current(A)", fmt_num(s.current, 6))
        elif isinstance(s, CCCV):
            st = _Step(f"{n}-cccv", "CCCV", fmt_num(s.current, 6), fmt_num(s.voltage, 6), "0")
        else:
            assert isinstance(s, ConstantVoltage)
            st = _Step(f"{n}-cv {s.direction.value}", "Voltage(V)", fmt_num(s.voltage, 6))
        if s.label:
            st.fields["m_szLabel"] += f" {s.label}"
        st.limits = [_end_limit(e, s) for e in s.ends] + [_LOG]
        steps.append(st)
    check_step_count(protocol, len(steps), rules)
    lim = protocol.limits
    t_max_c = lim.temperature_max - 273.15
    aux = " ; ".join(f"{j}^{1 if j == 1 else 0}" for j in range(12))
    glob = {
        "m_uMUID": "0",
        "m_szCreator": "battlab protocols",
        "m_szComments": protocol.name,
        "m_uMaxTimesOfUnsafe": "3",
        "m_bLogChanNormalData": "1",
        "m_bCheckCurrentSafety": "1",
        "m_bDefaultCurrentSafetyMode": "0",
        "m_CurrentSafetyScope": f"{-lim.current_max:.6f}^{lim.current_max:.6f}",
        "m_bCheckVoltageSafety": "1",
        "m_bDefaultVoltageSafetyMode": "0",
        "m_VoltageSafetyScope": f"{lim.voltage_min:.6f}^{lim.voltage_max:.6f}",
        "m_bCheckPowerSafety": "0",
        "m_PowerSafetyScope": "0.000000^0.000000",
        "m_AuxSafetyEnabled": aux,
        "m_AuxTempSafetyScope": f"-100.000000^{t_max_c:.6f}",
        "m_uStepNum": str(len(steps)),
        "m_uFormulaNum": "0",
        "m_uPulseNum": "0",
        "m_uCVNum": "0",
        "m_uAddInNum": "0",
    }
    blocks = [
        ["[Version Section]", "Current_Version=Schedule Version 7.00.13"],
        ["[Schedule]", *[f"{k}={v}" for k, v in glob.items()]],
    ]
    for i, st in enumerate(steps):
        st.fields["m_uLimitNum"] = str(len(st.limits))
        blocks.append([f"[Schedule_Step{i}]", *[f"{k}={v}" for k, v in st.fields.items()]])
        for j, li in enumerate(st.limits):
            blocks.append([f"[Schedule_Step{i}_Limit{j}]", *[f"{k}={v}" for k, v in li.items()]])
    path = Path(out_dir) / f"{safe_name(name or protocol.name)}.sdu"
    path.write_bytes(("\r\n".join(line for b in blocks for line in b) + "\r\n").encode("latin-1"))
    return ExportResult((path,))


# --- re-import ---------------------------------------------------------------------------------------------


def _sections(text: str) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    parts = re.split(r"^\[(.+)\]\s*$", text, flags=re.MULTILINE)
    for head, body in zip(parts[1::2], parts[2::2], strict=True):
        out[head] = dict(line.split("=", 1) for line in body.splitlines() if "=" in line)
    return out


def _holds(left: float, sign: str, right: float) -> bool:
    return {
        "<": left < right,
        "<=": left <= right,
        ">": left > right,
        ">=": left >= right,
        "=": left == right,
    }[sign]


def read(path: str | Path) -> ReadBack:
    """Re-import a schedule written by :func:`write` by playing its control flow."""
    path = Path(path)
    sec = _sections(path.read_bytes().decode("latin-1"))
    glob = sec.get("Schedule")
    if glob is None:
        raise InputError(f"{path}: no [Schedule] section")
    n = int(glob["m_uStepNum"])
    steps = [sec[f"Schedule_Step{i}"] for i in range(n)]
    limits = [[sec[f"Schedule_Step{i}_Limit{j}"] for j in range(int(s["m_uLimitNum"]))] for i, s in enumerate(steps)]
    by_label = {s["m_szLabel"]: i for i, s in enumerate(steps)}
    items: list[Canonical] = []
    tc = [0] * 5
    pc, guard = 0, 0
    while pc < n:
        guard += 1
        if guard > 10_000_000:
            raise InputError(f"{path}: control flow does not terminate")
        s, lims = steps[pc], limits[pc]
        ctrl = s["m_szStepCtrlType"]
        if ctrl == "Set Variable(s)":
            reset, inc = int(s["m_szCtrlValue"] or 0), int(s["m_szExtCtrlValue1"] or 0)
            for c in range(1, 5):
                if reset & 2 ** (15 + c):
                    tc[c] = 0
                if inc & 2**c:
                    tc[c] += 1
            nxt = pc + 1
            for li in lims:
                left = li["Equation0_szLeft"]
                value = float(tc[int(left[-1])]) if left.startswith("TC_Counter") else 1.0
                if _holds(value, li["Equation0_szCompareSign"], float(li["Equation0_szRight"])):
                    goto = li["m_szGotoStep"]
                    nxt = pc + 1 if goto == "Next Step" else by_label[goto]
                    break
            pc = nxt
            continue
        items.append(_read_step(path, s, [li for li in lims if li["m_bStepLimit"] == "1"]))
        pc += 1
    vmin, vmax = (float(x) for x in glob["m_VoltageSafetyScope"].split("^"))
    imax = float(glob["m_CurrentSafetyScope"].split("^")[1])
    tmax = float(glob["m_AuxTempSafetyScope"].split("^")[1]) + 273.15
    return ReadBack(merge_holds(items), voltage_min=vmin, voltage_max=vmax, current_max=imax, temperature_max=tmax)


def _read_step(path: Path, s: dict[str, str], lims: list[dict[str, str]]) -> Canonical:
    ctrl, label = s["m_szStepCtrlType"], s["m_szLabel"]
    charging = True
    if ctrl in ("Current(A)", "CCCV"):
        charging = float(s["m_szCtrlValue"]) > 0
    elif ctrl == "Voltage(V)":
        m = re.match(r"\d+-cv (charge|discharge)\b", label)
        if m is None:
            raise InputError(f"{path}: CV step {label!r} does not name its direction ('<n>-cv charge|discharge')")
        charging = m.group(1) == "charge"
    ends = []
    for li in lims:
        left, sign, right = (
            li["Equation0_szLeft"],
            li["Equation0_szCompareSign"],
            float(li["Equation0_szRight"]),
        )
        op = Comparison.GE if ">" in sign else Comparison.LE
        if left == "PV_CHAN_Step_Time":
            ends.append(EndCondition(Quantity.TIME, Comparison.GE, right))
        elif left == "PV_CHAN_Voltage":
            ends.append(EndCondition(Quantity.VOLTAGE, op, right))
        elif left in ("PV_CHAN_CV_Stage_Current", "PV_CHAN_Current"):
            if not charging:
                op = Comparison.LE if op is Comparison.GE else Comparison.GE
            ends.append(EndCondition(Quantity.CURRENT, op, abs(right)))
        elif left in ("PV_CHAN_Charge_Capacity", "PV_CHAN_Discharge_Capacity"):
            ends.append(EndCondition(Quantity.CAPACITY, Comparison.GE, right))
        else:
            raise InputError(f"{path}: step {label!r}: limit on {left} is not one this exporter writes")
    if ctrl == "Rest":
        step: Step = Rest(tuple(ends))
    elif ctrl == "Current(A)":
        step = ConstantCurrent(float(s["m_szCtrlValue"]), tuple(ends))
    elif ctrl == "CCCV":
        step = CCCV(float(s["m_szCtrlValue"]), float(s["m_szExtCtrlValue1"]), tuple(ends))
    elif ctrl == "Voltage(V)":
        direction = Direction.CHARGE if charging else Direction.DISCHARGE
        step = ConstantVoltage(float(s["m_szCtrlValue"]), tuple(ends), direction)
    else:
        raise InputError(f"{path}: step {label!r}: control type {ctrl!r} is not one this exporter writes")
    d = time_only(step)
    if d is not None:
        return Hold(d, step.current if isinstance(step, ConstantCurrent) else 0.0)
    return step


__all__ = ["RULES", "Repeat", "read", "write"]
