"""BioLogic BT-Lab / EC-Lab Modulo Bat settings export (``<name>.mps``).

Layout (learned from the BT-Lab settings files shipped as templates with TRI's BEEP, recorded on BCS-805 and
BCS-815 cyclers, and from aurora-unicycler's Modulo Bat writer):

* Text in cp1252, CRLF: a header (``BT-LAB SETTING FILE``, the device, the safety limits, comments), then
  ``Technique : 1`` / ``Modulo Bat`` and one row per parameter whose first 20 characters are the parameter name
  and every following 20-character column one *sequence* (``Ns`` = 0, 1, ...).
* The technique block has the 62 rows BT-Lab writes for Modulo Bat, in its order (``Ns`` ... ``Bandwidth``,
  three limits ``lim1..3`` and three records ``rec1..3``); see :data:`ROWS`. The header names the BCS-815
  (±15 A per channel), the BioLogic cycler for a 2.7 Ah cell run at 5C; BCS cyclers are driven by BT-Lab,
  hence ``BT-LAB SETTING FILE``. EC-Lab writes the same structure (``EC-LAB SETTING FILE``) with rows that
  vary between its versions (EC-Lab 11.5 adds ``current/potential``, ``charge/discharge_1``, ``N1``,
  ``ctrl4..5``, ``ctrl_tM``).
* ``Rest``; ``CC`` with ``ctrl1_val`` = |I| in mA and the sign in the ``charge/discharge`` row (``Charge`` =
  positive current); ``CV`` with ``ctrl1_val`` in V (vs ``Ref``) and the direction in ``charge/discharge``.
  Modulo Bat has no combined CC-CV sequence: a CCCV step is written as a CC sequence up to the voltage and a
  CV sequence there, and reads back as those two (see :func:`protocols.export.program.split_cccv`).
* Ends are limits (at most three per sequence): ``Time > t s``, ``Ecell >``/``<`` V, ``|I| <``/``>`` mA,
  ``|Q| > Ah`` (charge of the sequence), each with action ``Next sequence``.
* A sampled profile becomes one sequence per zero-order-hold segment (``Rest`` or ``CC`` ending on time);
  runs that repeat become a ``Loop`` sequence (``ctrl_seq`` = first sequence of the body, ``ctrl_repeat`` =
  count - 1, as in aurora-unicycler and BEEP's templates).
* Safety limits go to the header's ``Safety Limits`` block (``Ecell min``/``Ecell max``/``|I| max``); the
  temperature limit has no field here and is reported as a note.
* The I range is one fixed range for every sequence (``10 mA``, ``100 mA`` or ``10 A``, the BCS-815 ranges in
  BEEP's templates), the smallest that holds the safety current: Modulo Bat has no ``Auto`` range for CC
  sequences (aurora-unicycler's note for EC-Lab 11.5), and the range may change between sequences only after
  a rest, so a single range avoids both. That the 10 A range covers the BCS-815's ±15 A is assumed, not
  checked; the export notes it when the safety current exceeds 10 A.

What BEEP's reader (``beep.protocol.biologic.Settings``) needs, and why the earlier files failed in it: it
takes the 62 lines after the ``Modulo Bat`` line as the technique (so the block must have exactly BT-Lab's 62
rows; the earlier 65-row block, EC-Lab 11.5's rows with three limits, spilled its last three rows into the
header), and it splits every
other line that contains ``:`` at ``" : "``, so the ``Safety Limits :`` line that BT-Lab writes (and BEEP's own
Maccor converter writes) stops it with ``ValueError``. The header therefore writes ``Safety Limits : `` with
a trailing space, the one deviation from BT-Lab's own text, which reads as the same key with an empty
value, as ``Electrode material : `` does in BT-Lab's files. BEEP's reader checks no software version line,
and BT-Lab's own files (BEEP's templates) carry none, so none is written.

Resolution and limits (assumptions, not checked against BioLogic's documentation): times are written to 1 ms
and a sequence lasts at least 1 ms, currents to 1 uA (mA with 3 decimals), voltages to 1 uV; a technique
holds at most 1000 sequences.
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
    where,
)
from protocols.export.program import Canonical, Hold, Repeat, merge_holds, split_cccv, time_only
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

RULES = FormatRules(
    label="BioLogic Modulo Bat",
    time_resolution_s=0.001,
    min_duration_s=0.001,
    current_resolution_a=1e-6,
    max_steps=1000,
    loops=True,
)
WIDTH = 20
MAX_LIMITS = 3

#: The Modulo Bat rows BT-Lab writes, in its order (BEEP's reader takes exactly this many).
ROWS = (
    "Ns",
    "ctrl_type",
    "Apply I/C",
    "ctrl1_val",
    "ctrl1_val_unit",
    "ctrl1_val_vs",
    "ctrl2_val",
    "ctrl2_val_unit",
    "ctrl2_val_vs",
    "ctrl3_val",
    "ctrl3_val_unit",
    "ctrl3_val_vs",
    "N",
    "charge/discharge",
    "ctrl_seq",
    "ctrl_repeat",
    "ctrl_trigger",
    "ctrl_TO_t",
    "ctrl_TO_t_unit",
    "ctrl_Nd",
    "ctrl_Na",
    "ctrl_corr",
    "lim_nb",
    *(f"lim{j}_{f}" for j in (1, 2, 3) for f in ("type", "comp", "Q", "value", "value_unit", "action", "seq")),
    "rec_nb",
    *(f"rec{j}_{f}" for j in (1, 2, 3) for f in ("type", "value", "value_unit")),
    "E range min (V)",
    "E range max (V)",
    "I Range",
    "I Range min",
    "I Range max",
    "I Range init",
    "auto rest",
    "Bandwidth",
)
#: Fixed I ranges [A] and their labels, smallest first (the BCS-815 ranges in BT-Lab's files).
I_RANGES = ((0.01, "10 mA"), (0.1, "100 mA"), (10.0, "10 A"))


def i_range(current_max: float) -> str:
    """The smallest fixed I range holding ``current_max`` [A] (the top range above it)."""
    return next((label for top, label in I_RANGES if current_max <= top * (1 + 1e-12)), I_RANGES[-1][1])


def _blank(ns: int, current_range: str) -> dict[str, str]:
    d = dict.fromkeys(ROWS, "")
    d.update(
        {
            "Ns": str(ns),
            "Apply I/C": "I",
            "N": "1.00",
            "charge/discharge": "Charge",
            "ctrl_seq": "0",
            "ctrl_repeat": "0",
            "ctrl_trigger": "Falling Edge",
            "ctrl_TO_t": "0.000",
            "ctrl_TO_t_unit": "d",
            "ctrl_Nd": "6",
            "ctrl_Na": "1",
            "ctrl_corr": "0",
            "lim_nb": "0",
            "rec_nb": "1",
            "E range min (V)": "0.000",
            "E range max (V)": "5.000",
            "I Range": current_range,
            "I Range min": "Unset",
            "I Range max": "Unset",
            "I Range init": "Unset",
            "auto rest": "0",
            "Bandwidth": "5",
        }
    )
    # unused limits and records hold BT-Lab's defaults: a zero time
    for j in (1, 2, 3):
        d.update(
            {
                f"lim{j}_type": "Time",
                f"lim{j}_comp": "<",
                f"lim{j}_Q": "Q limit",
                f"lim{j}_value": "0.000",
                f"lim{j}_value_unit": "s",
                f"lim{j}_action": "Next sequence",
                f"lim{j}_seq": str(ns + 1),
                f"rec{j}_type": "Time",
                f"rec{j}_value": "0.000",
                f"rec{j}_value_unit": "s",
            }
        )
    d["rec1_value"] = "1.000"
    return d


def _set_limits(seq: dict[str, str], ends: list[tuple[str, str, str, str]]) -> None:
    seq["lim_nb"] = str(len(ends))
    for j, (typ, comp, value, unit) in enumerate(ends, start=1):
        seq.update({f"lim{j}_type": typ, f"lim{j}_comp": comp, f"lim{j}_value": value, f"lim{j}_value_unit": unit})


def _limit(e: EndCondition) -> tuple[str, str, str, str]:
    comp = ">" if e.op is Comparison.GE else "<"
    if e.quantity is Quantity.TIME:
        return ("Time", ">", fmt_num(e.value, 3), "s")
    if e.quantity is Quantity.VOLTAGE:
        return ("Ecell", comp, fmt_num(e.value, 6), "V")
    if e.quantity is Quantity.CURRENT:
        return ("|I|", comp, fmt_num(e.value * 1e3, 3), "mA")
    return ("|Q|", ">", fmt_num(e.value, 6), "A.h")


def _hold(ns: int, h: Hold, current_range: str) -> dict[str, str]:
    seq = _blank(ns, current_range)
    if h.current == 0:
        seq["ctrl_type"] = "Rest"
    else:
        seq.update(
            {
                "ctrl_type": "CC",
                "ctrl1_val": fmt_num(abs(h.current) * 1e3, 3),
                "ctrl1_val_unit": "mA",
                "ctrl1_val_vs": "<None>",
                "charge/discharge": "Charge" if h.current > 0 else "Discharge",
            }
        )
    _set_limits(seq, [("Time", ">", fmt_num(h.duration, 3), "s")])
    return seq


def write(protocol: Protocol, out_dir: Path, *, name: str | None = None, rules: FormatRules = RULES) -> ExportResult:
    """Write ``<name>.mps`` into ``out_dir``."""
    protocol.check()
    check_times(protocol, rules)
    proto = split_cccv(protocol)
    lim = protocol.limits
    current_range = i_range(lim.current_max)
    seqs: list[dict[str, str]] = []
    for k, s in enumerate(proto.steps, start=1):
        if len(s.ends) > MAX_LIMITS:
            raise InputError(f"{where(proto, k, s)}: Modulo Bat takes at most {MAX_LIMITS} limits per sequence")
        if isinstance(s, ProfileStep):
            for it in profile_plan(proto, k, s, rules):
                if isinstance(it, Hold):
                    seqs.append(_hold(len(seqs), it, current_range))
                    continue
                first = len(seqs)
                for h in it.body:
                    seqs.append(_hold(len(seqs), h, current_range))
                loop = _blank(len(seqs), current_range)
                loop.update({"ctrl_type": "Loop", "ctrl_seq": str(first), "ctrl_repeat": str(it.count - 1)})
                loop["rec_nb"] = "0"
                seqs.append(loop)
            continue
        seq = _blank(len(seqs), current_range)
        if isinstance(s, Rest):
            seq["ctrl_type"] = "Rest"
        elif isinstance(s, ConstantCurrent):
            seq.update(
                {
                    "ctrl_type": "CC",
                    "ctrl1_val": fmt_num(abs(s.current) * 1e3, 3),
                    "ctrl1_val_unit": "mA",
                    "ctrl1_val_vs": "<None>",
                    "charge/discharge": "Charge" if s.current > 0 else "Discharge",
                }
            )
        elif isinstance(s, ConstantVoltage):
            seq.update(
                {
                    "ctrl_type": "CV",
                    "ctrl1_val": fmt_num(s.voltage, 6),
                    "ctrl1_val_unit": "V",
                    "ctrl1_val_vs": "Ref",
                    "charge/discharge": "Charge" if s.direction is Direction.CHARGE else "Discharge",
                }
            )
        _set_limits(seq, [_limit(e) for e in s.ends])
        seqs.append(seq)
    check_step_count(protocol, len(seqs), rules, "sequences")
    # the comment is one line of cp1252 text: line breaks become spaces, other characters '?'
    comment = " ".join(protocol.name.split()).encode("cp1252", "replace").decode("cp1252")
    header = [
        "BT-LAB SETTING FILE",
        "",
        "Number of linked techniques : 1",
        "",
        "Device : BCS-815",
        "Ecell ctrl range : min = 0.00 V, max = 5.00 V",
        # BT-Lab writes no space after this colon; BEEP's reader needs ' : ' in every line with a colon
        "Safety Limits : ",
        f"\tEcell min = {fmt_num(lim.voltage_min, 6)} V",
        f"\tEcell max = {fmt_num(lim.voltage_max, 6)} V",
        f"\t|I| max = {fmt_num(lim.current_max, 6)} A",
        "\tfor t > 100 ms",
        f"Comments : {comment}",
        "Cycle Definition : Charge/Discharge alternance",
        "Do not turn to OCV between techniques",
        "",
        "Technique : 1",
        "Modulo Bat",
    ]
    rows = [key.ljust(WIDTH) + "".join(seq[key].ljust(WIDTH) for seq in seqs) for key in ROWS]
    path = Path(out_dir) / f"{safe_name(name or protocol.name)}.mps"
    path.write_bytes(("\r\n".join([*header, *rows]) + "\r\n").encode("cp1252"))
    notes = [f"BioLogic: the temperature limit {lim.temperature_max - 273.15:g} degC is not in the settings file"]
    if lim.current_max > I_RANGES[-1][0]:
        notes.append(
            f"BioLogic: the I range is {current_range} for a safety current of {lim.current_max:g} A; check that "
            "your channel's range reaches it"
        )
    return ExportResult((path,), tuple(notes))


# --- re-import ---------------------------------------------------------------------------------------------


def read(path: str | Path) -> ReadBack:
    """Re-import a settings file written by :func:`write` by playing its sequences and loops."""
    path = Path(path)
    lines = path.read_bytes().decode("cp1252").splitlines()
    try:
        start = lines.index("Modulo Bat") + 1
    except ValueError:
        raise InputError(f"{path}: no Modulo Bat technique") from None
    table = {}
    for line in lines[start:]:
        if not line.strip():
            continue
        key = line[:WIDTH].strip()
        body = line[WIDTH:]
        table[key] = [body[i : i + WIDTH].strip() for i in range(0, len(body), WIDTH)]
    n = len(table["Ns"])
    seqs = [{key: (vals[i] if i < len(vals) else "") for key, vals in table.items()} for i in range(n)]
    items: list[Canonical] = []
    done = [0] * n
    pc, guard = 0, 0
    while pc < n:
        guard += 1
        if guard > 10_000_000:
            raise InputError(f"{path}: loops do not terminate")
        s = seqs[pc]
        if s["ctrl_type"] == "Loop":
            if done[pc] < int(s["ctrl_repeat"]):
                done[pc] += 1
                pc = int(s["ctrl_seq"])
            else:
                done[pc] = 0
                pc += 1
            continue
        items.append(_read_seq(path, s))
        pc += 1
    head = "\n".join(lines[:start])

    def grab(pattern: str) -> float | None:
        m = re.search(pattern, head)
        return float(m.group(1)) if m else None

    return ReadBack(
        merge_holds(items),
        voltage_min=grab(r"Ecell min = ([-0-9.]+) V"),
        voltage_max=grab(r"Ecell max = ([-0-9.]+) V"),
        current_max=grab(r"\|I\| max = ([-0-9.]+) A"),
    )


def _read_seq(path: Path, s: dict[str, str]) -> Canonical:
    ends = []
    for j in range(1, int(s["lim_nb"]) + 1):
        typ, comp, value = s[f"lim{j}_type"], s[f"lim{j}_comp"], float(s[f"lim{j}_value"])
        op = Comparison.GE if comp == ">" else Comparison.LE
        if typ == "Time":
            ends.append(EndCondition(Quantity.TIME, Comparison.GE, value))
        elif typ == "Ecell":
            ends.append(EndCondition(Quantity.VOLTAGE, op, value))
        elif typ == "|I|":
            ends.append(EndCondition(Quantity.CURRENT, op, value / 1e3))
        elif typ == "|Q|":
            ends.append(EndCondition(Quantity.CAPACITY, Comparison.GE, value))
        else:
            raise InputError(f"{path}: sequence {s['Ns']}: limit type {typ!r} is not one this exporter writes")
    sign = 1.0 if s["charge/discharge"] == "Charge" else -1.0
    ctrl = s["ctrl_type"]
    if ctrl == "Rest":
        step: Step = Rest(tuple(ends))
    elif ctrl == "CC":
        step = ConstantCurrent(sign * float(s["ctrl1_val"]) / 1e3, tuple(ends))
    elif ctrl == "CV":
        step = ConstantVoltage(
            float(s["ctrl1_val"]), tuple(ends), Direction.CHARGE if sign > 0 else Direction.DISCHARGE
        )
    else:
        raise InputError(f"{path}: sequence {s['Ns']}: type {ctrl!r} is not one this exporter writes")
    d = time_only(step)
    if d is not None:
        return Hold(d, step.current if isinstance(step, ConstantCurrent) else 0.0)
    return step


__all__ = ["RULES", "Repeat", "read", "write"]
