"""Maccor procedure export: ``<name>.000`` (XML procedure) plus one ``<name>_<k>.MWF`` per profile step.

Conventions (learned from the procedure and waveform files of TRI's open-source BEEP generator):

* Steps are ``Rest``, ``Charge``/``Dischrge`` with ``StepMode`` ``Current`` (value = |I| in A) or ``Voltage``
  (value in V), and ``FastWave`` (value = waveform name, < 25 characters); the last step is ``End``. The
  step *type* carries the sign (Charge = positive current in battlab's convention); values are magnitudes.
* CCCV = a Current step with a ``<Limits><Voltage>`` clamp; CV = a Voltage step with a
  ``<Limits><Current>`` clamp at the safety current.
* Ends: ``StepTime`` (``HH:MM:SS`` or ``HH:MM:SS.ss``), ``Voltage`` (>=, <=), ``Current`` (|I|),
  ``Capacity`` (Ah of the step); the goto step is the next one (3 digits, 1-based).
* Safety: every step except FastWave gets ``Voltage >= voltage_max`` and ``Voltage <= voltage_min`` ends
  that go to the End step (``ChanSafetyEnd``); current and temperature limits are not written (set them in
  the channel's safety limits) - the export notes this.
* ``.MWF`` waveform: one tab-separated row per constant-current segment: state (``C`` charge, ``D``
  discharge; a rest is ``D`` at 0 A), mode ``I``, |I| [A] (6 decimals), limit ``V`` and its voltage clamp
  (voltage_max when charging, voltage_min when discharging), duration [s] (4 decimals), end ``V``
  ``>=``/``<=`` at the same safety voltage, report ``T`` every 1 s, range ``A`` (auto).

Resolution and limits (assumptions, not checked against Maccor's documentation): segment and step times are
multiples of 10 ms and at least 10 ms; currents are written to 1 uA; a waveform holds at most 65 535 segments.
Profiles are never looped (FastWave has no loops): every zero-order-hold segment is one row.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.sax.saxutils import escape

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
from protocols.export.program import Canonical, Hold, expand, merge_holds, time_only
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
)

RULES = FormatRules(
    label="Maccor FastWave",
    time_resolution_s=0.01,
    min_duration_s=0.01,
    current_resolution_a=1e-6,
    max_steps=65535,
    loops=False,
)
WAVEFORM_NAME_MAX = 24

_TYPES = {
    "rest": "  Rest  ",
    "charge": " Charge ",
    "discharge": "Dischrge",
    "fastwave": "FastWave",
    "end": "  End   ",
}
_MODES = {"current": "Current ", "voltage": "Voltage ", "": "        "}
_END_TYPES = {
    Quantity.TIME: "StepTime",
    Quantity.VOLTAGE: "Voltage ",
    Quantity.CURRENT: "Current ",
    Quantity.CAPACITY: "Capacity",
}
_OPERS = {Comparison.GE: "&gt;= ", Comparison.LE: "&lt;= "}


def hms(seconds: float) -> str:
    """Maccor step time: ``HH:MM:SS`` or ``HH:MM:SS.ss``."""
    cs = round(seconds * 100)
    h, rem = divmod(cs, 360000)
    m, rem = divmod(rem, 6000)
    s, frac = divmod(rem, 100)
    return f"{h:02d}:{m:02d}:{s:02d}" + (f".{frac:02d}" if frac else "")


def parse_hms(text: str) -> float:
    """Seconds from ``HH:MM:SS[.ss]`` (empty fields count as 0, as in ``::.01``)."""
    parts = text.strip().split(":")
    if len(parts) != 3:
        raise InputError(f"Maccor time {text!r}: expected HH:MM:SS")
    h, m, s = (float(p) if p.strip() else 0.0 for p in parts)
    return 3600 * h + 60 * m + s


def _end_entry(end_type: str, oper: str, goto: int, value: str, safety: bool = False) -> list[str]:
    lines = [
        "        <EndEntry>",
        f"          <EndType>{end_type}</EndType>",
        "          <SpecialType> </SpecialType>",
        f"          <Oper>{oper}</Oper>",
        f"          <Step>{goto:03d}</Step>",
        f"          <Value>{value}</Value>",
    ]
    if safety:
        lines.append("          <ChanSafetyEnd>True</ChanSafetyEnd>")
    return [*lines, "        </EndEntry>"]


def _end_value(e: EndCondition) -> str:
    if e.quantity is Quantity.TIME:
        return hms(e.value)
    return fmt_num(e.value, 6)


def _test_step(
    step_type: str,
    mode: str,
    value: str,
    *,
    limits: list[str] | None = None,
    ends: list[list[str]] | None = None,
    report: bool = True,
    note: str = "",
) -> list[str]:
    out = [
        "    <TestStep>",
        f"      <StepType>{step_type}</StepType>",
        f"      <StepMode>{mode}</StepMode>",
        f"      <StepValue>{escape(value)}</StepValue>",
    ]
    out += ["      <Limits>", *limits, "      </Limits>"] if limits else ["      <Limits/>"]
    if ends:
        out += ["      <Ends>", *[line for e in ends for line in e], "      </Ends>"]
    else:
        out.append("      <Ends/>")
    if report:
        out += [
            "      <Reports>",
            "        <ReportEntry>",
            "          <ReportType>StepTime</ReportType>",
            "          <Value>00:00:01</Value>",
            "        </ReportEntry>",
            "      </Reports>",
        ]
    else:
        out.append("      <Reports/>")
    range_ = "A" if report else ""
    opt = "N" if report else ""
    out += [
        f"      <Range>{range_}</Range>",
        f"      <Option1>{opt}</Option1>",
        f"      <Option2>{opt}</Option2>",
        f"      <Option3>{opt}</Option3>",
        f"      <StepNote>{escape(note)}</StepNote>",
        "    </TestStep>",
    ]
    return out


def _mwf_rows(holds: list[Hold], protocol: Protocol) -> list[str]:
    lim = protocol.limits
    rows = []
    for h in holds:
        charge = h.current > 0
        state = "C" if charge else "D"
        v_lim = lim.voltage_max if charge else lim.voltage_min
        oper = ">=" if charge else "<="
        rows.append(
            "\t".join(
                [
                    state,
                    "I",
                    fmt_num(abs(h.current), 6),
                    "V",
                    fmt_num(v_lim, 6),
                    f"{h.duration:.4f}",
                    "V",
                    oper,
                    fmt_num(v_lim, 6),
                    "T",
                    "1.0000",
                    "A",
                ]
            )
        )
    return rows


def write(protocol: Protocol, out_dir: Path, *, name: str | None = None, rules: FormatRules = RULES) -> ExportResult:
    """Write the procedure and its waveform files into ``out_dir``."""
    protocol.check()
    check_times(protocol, rules)
    base = safe_name(name or protocol.name)
    out_dir = Path(out_dir)
    n_steps = len(protocol.steps)
    end_no = n_steps + 1
    lim = protocol.limits
    safety = [
        _end_entry(_END_TYPES[Quantity.VOLTAGE], _OPERS[Comparison.GE], end_no, fmt_num(lim.voltage_max, 6), True),
        _end_entry(_END_TYPES[Quantity.VOLTAGE], _OPERS[Comparison.LE], end_no, fmt_num(lim.voltage_min, 6), True),
    ]
    lines: list[str] = []
    waveforms: list[tuple[Path, list[str]]] = []
    for k, s in enumerate(protocol.steps, start=1):
        nxt = k + 1
        ends = [_end_entry(_END_TYPES[e.quantity], _oper(e), nxt, _end_value(e)) for e in s.ends] + safety
        if isinstance(s, Rest):
            lines += _test_step(_TYPES["rest"], _MODES[""], "", ends=ends, note=s.label)
        elif isinstance(s, ConstantCurrent | CCCV):
            typ = _TYPES["charge" if s.current > 0 else "discharge"]
            clamp = [f"        <Voltage>{fmt_num(s.voltage, 6)}</Voltage>"] if isinstance(s, CCCV) else None
            lines += _test_step(
                typ, _MODES["current"], fmt_num(abs(s.current), 6), limits=clamp, ends=ends, note=s.label
            )
        elif isinstance(s, ConstantVoltage):
            typ = _TYPES["charge" if s.direction is Direction.CHARGE else "discharge"]
            clamp = [f"        <Current>{fmt_num(lim.current_max, 6)}</Current>"]
            lines += _test_step(typ, _MODES["voltage"], fmt_num(s.voltage, 6), limits=clamp, ends=ends, note=s.label)
        elif isinstance(s, ProfileStep):
            holds = expand(profile_plan(protocol, k, s, rules))
            check_step_count(protocol, len(holds), rules, "waveform segments")
            wname = _waveform_name(base, k, n_steps)
            waveforms.append((out_dir / f"{wname}.MWF", _mwf_rows(holds, protocol)))
            lines += _test_step(_TYPES["fastwave"], _MODES[""], wname, report=False, note=s.label)
    lines += _test_step(_TYPES["end"], _MODES[""], "", report=False)
    text = "\n".join(
        [
            '<?xml version="1.0" encoding="UTF-8"?>',
            '<?maccor-application progid="Maccor Procedure File"?>',
            "<MaccorTestProcedure>",
            "  <header>",
            "    <BuildTestVersion>",
            "      <major>1</major>",
            "      <minor>5</minor>",
            "      <release>7006</release>",
            "      <build>32043</build>",
            "    </BuildTestVersion>",
            "    <FileFormatVersion>",
            "      <BTVersion>11</BTVersion>",
            "    </FileFormatVersion>",
            "    <ProcDesc>",
            f"      <desc>{escape(protocol.name)}</desc>",
            "    </ProcDesc>",
            "  </header>",
            "  <ProcSteps>",
            *lines,
            "  </ProcSteps>",
            "</MaccorTestProcedure>",
            "",
        ]
    )
    path = out_dir / f"{base}.000"
    path.write_text(text, encoding="utf-8")
    files = [path]
    for wpath, rows in waveforms:
        wpath.write_text("\n".join(rows) + "\n", encoding="ascii")
        files.append(wpath)
    notes = (
        f"Maccor: current limit {lim.current_max:g} A and temperature limit "
        f"{lim.temperature_max - 273.15:g} degC are not in the procedure; "
        "set them in the channel's safety limits",
    )
    return ExportResult(tuple(files), notes)


def _oper(e: EndCondition) -> str:
    return " = " if e.quantity is Quantity.TIME else _OPERS[e.op]


def _waveform_name(base: str, k: int, n_steps: int) -> str:
    suffix = f"_{k}"
    return base[: WAVEFORM_NAME_MAX - len(suffix)] + suffix


# --- re-import ---------------------------------------------------------------------------------------------


def _text(el: ET.Element | None, tag: str) -> str:
    if el is None:
        return ""
    child = el.find(tag)
    return (child.text or "").strip() if child is not None else ""


def read_mwf(path: str | Path) -> list[Hold]:
    """Holds of a ``.MWF`` waveform (current positive = charge)."""
    holds = []
    for n, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), start=1):
        if not line.strip():
            continue
        f = line.split("\t")
        if len(f) < 12 or f[0] not in ("C", "D") or f[1] != "I":
            raise InputError(f"{path}, line {n}: not a current-mode waveform row: {line!r}")
        sign = 1.0 if f[0] == "C" else -1.0
        holds.append(Hold(float(f[5]), sign * float(f[2]) + 0.0))
    return holds


def read(path: str | Path) -> ReadBack:
    """Re-import a procedure written by :func:`write` (waveforms are read from beside it)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(f"{path}: not valid XML: {exc}") from None
    steps = root.findall("./ProcSteps/TestStep")
    end_no = next((k for k, st in enumerate(steps, start=1) if _text(st, "StepType") == "End"), len(steps))
    items: list[Canonical] = []
    vmin = vmax = None
    for st in steps:
        typ, mode, value = _text(st, "StepType"), _text(st, "StepMode"), _text(st, "StepValue")
        if typ == "End":
            break
        ends = []
        for e in st.findall("./Ends/EndEntry"):
            et, op, val = _text(e, "EndType"), _text(e, "Oper"), _text(e, "Value")
            goto = int(_text(e, "Step"))
            if goto == end_no and _text(e, "ChanSafetyEnd") == "True":
                if op == ">=":
                    vmax = float(val)
                else:
                    vmin = float(val)
                continue
            q = {"StepTime": Quantity.TIME, "Voltage": Quantity.VOLTAGE, "Current": Quantity.CURRENT}.get(
                et, Quantity.CAPACITY
            )
            v = parse_hms(val) if q is Quantity.TIME else float(val)
            ends.append(EndCondition(q, Comparison.LE if op == "<=" else Comparison.GE, v))
        label = _text(st, "StepNote")
        if typ == "FastWave":
            items.extend(read_mwf(path.parent / f"{value}.MWF"))
            continue
        if typ == "Rest":
            step: object = Rest(tuple(ends), label)
        elif mode == "Current":
            sign = 1.0 if typ == "Charge" else -1.0
            clamp = _text(st.find("Limits"), "Voltage")
            if clamp:
                step = CCCV(sign * float(value), float(clamp), tuple(ends), label)
            else:
                step = ConstantCurrent(sign * float(value), tuple(ends), label)
        elif mode == "Voltage":
            direction = Direction.CHARGE if typ == "Charge" else Direction.DISCHARGE
            step = ConstantVoltage(float(value), tuple(ends), direction, label)
        else:
            raise InputError(f"{path}: step type {typ!r} mode {mode!r} is not one this exporter writes")
        d = time_only(step)  # type: ignore[arg-type]
        if d is not None:
            items.append(Hold(d, step.current if isinstance(step, ConstantCurrent) else 0.0))
        else:
            items.append(step)  # type: ignore[arg-type]
    return ReadBack(merge_holds(items), voltage_min=vmin, voltage_max=vmax)
