"""TRI's BEEP reads our Maccor, Arbin and BioLogic exports with its own parsers.

Each protocol is exported, parsed by BEEP (``Procedure``, ``Schedule``, ``Settings``), and what BEEP read is
compared with the protocol: step count, step types, currents, voltages and ends. BEEP also writes what it read
back out; that file must equal ours byte for byte, so no line of ours was left unread or misread.

BEEP is a test-only dependency installed without its own dependencies (its ``msgpack-python`` requirement
overwrites the ``msgpack`` package that dask.distributed needs): ``pip install --no-deps beep==2026.2.7``; the
``test`` extra carries the packages its protocol readers import. Without BEEP these tests skip, and fail in CI.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from tests.conftest import reference

reference("beep.protocol.biologic")

from beep.protocol.arbin import Schedule  # noqa: E402
from beep.protocol.biologic import Settings  # noqa: E402
from beep.protocol.maccor import Procedure  # noqa: E402
from test_protocols_export import golden_protocol  # noqa: E402

from protocols import (  # noqa: E402
    CCCV,
    ConstantCurrent,
    ConstantVoltage,
    Direction,
    ProfileStep,
    Protocol,
    PulseSpec,
    Rest,
    pulse_profile,
)
from protocols.drive_cycles import Cycle, drive_profile  # noqa: E402
from protocols.export import Format, export  # noqa: E402
from protocols.export.biologic import ROWS  # noqa: E402
from protocols.export.program import Hold, Repeat, expand, profile_items  # noqa: E402

# BEEP logs every call to stdout at DEBUG level
logging.getLogger("beep").setLevel(logging.WARNING)

FORMATS = (Format.MACCOR, Format.ARBIN, Format.BIOLOGIC)


def _cccv() -> Protocol:
    return Protocol("cccv", (CCCV(1.35, 4.2, ("current <= 0.054", "time >= 14400"), "C/2 CCCV"),))


def _rests() -> Protocol:
    steps = (
        Rest(("time >= 600",), "settle"),
        ConstantCurrent(-2.7, ("voltage <= 3.0", "time >= 3600"), "1C down"),
        Rest(("time >= 3600",), "relax"),
    )
    return Protocol("rests", steps)


def _pulses() -> Protocol:
    pulses = pulse_profile(PulseSpec(2.0, 1, 20.0, Direction.BOTH), charge_ah=0.005, id="pulses", soc0=0.6)
    return Protocol("pulses", (Rest(("time >= 60",)), ProfileStep(pulses, "pulses")))


def _drive() -> Protocol:
    return Protocol("dc1", (ProfileStep(drive_profile(Cycle.DC1, id="dc1", soc0=0.8), "DC1"),))


PROTOCOLS = {"cccv": _cccv, "rests": _rests, "pulses": _pulses, "drive": _drive, "golden": None}


def _protocol(name: str, fmt: Format) -> Protocol:
    make = PROTOCOLS[name]
    return golden_protocol(fmt) if make is None else make()


def _holds(step: ProfileStep, loops: bool) -> list[Hold | Repeat]:
    return list(profile_items(step.profile, loops=loops, current_quantum=1e-6))


# --- Maccor --------------------------------------------------------------------------------------------------


def _as_list(x: Any) -> list:
    if x is None:
        return []
    return x if isinstance(x, list) else [x]


@pytest.mark.parametrize("name", list(PROTOCOLS))
def test_beep_reads_maccor_procedures(name: str, tmp_path: Path) -> None:
    proto = _protocol(name, Format.MACCOR)
    result = export(proto, Format.MACCOR, tmp_path)
    proc = Procedure.from_file(str(result.path))
    steps = proc["MaccorTestProcedure"]["ProcSteps"]["TestStep"]
    steps = _as_list(steps)
    assert len(steps) == len(proto.steps) + 1 and steps[-1]["StepType"] == "End"
    lim = proto.limits
    for k, (s, st) in enumerate(zip(proto.steps, steps, strict=False), start=1):
        ends = _as_list((st["Ends"] or {}).get("EndEntry"))
        user_ends = [e for e in ends if e.get("ChanSafetyEnd") != "True"]
        if isinstance(s, ProfileStep):
            # BEEP's FastWave convention: the step names a .MWF (< 25 characters) beside the procedure
            assert st["StepType"] == "FastWave" and len(st["StepValue"]) < 25
            _check_mwf(tmp_path / f"{st['StepValue']}.MWF", s, lim.voltage_min, lim.voltage_max)
            continue
        safety = sorted((e["Oper"], float(e["Value"])) for e in ends if e.get("ChanSafetyEnd") == "True")
        assert safety == [("<=", lim.voltage_min), (">=", lim.voltage_max)]
        assert all(int(e["Step"]) == len(proto.steps) + 1 for e in ends if e.get("ChanSafetyEnd") == "True")
        assert all(int(e["Step"]) == k + 1 for e in user_ends)
        assert len(user_ends) == len(s.ends)
        if isinstance(s, Rest):
            assert st["StepType"] == "Rest"
        elif isinstance(s, ConstantVoltage):
            assert st["StepType"] == ("Charge" if s.direction is Direction.CHARGE else "Dischrge")
            assert st["StepMode"] == "Voltage" and float(st["StepValue"]) == s.voltage
            assert float(st["Limits"]["Current"]) == lim.current_max
        else:
            assert st["StepType"] == ("Charge" if s.current > 0 else "Dischrge")
            assert st["StepMode"] == "Current" and float(st["StepValue"]) == abs(s.current)
            clamp = (st["Limits"] or {}).get("Voltage")
            assert (float(clamp) if clamp else None) == (s.voltage if isinstance(s, CCCV) else None)
        for e, end in zip(user_ends, s.ends, strict=True):
            kind = {"time": "StepTime", "voltage": "Voltage", "current": "Current", "capacity": "Capacity"}
            assert e["EndType"] == kind[end.quantity.value]
            if end.quantity.value == "time":
                h, m, sec = (float(x) for x in e["Value"].split(":"))
                assert (e["Oper"], 3600 * h + 60 * m + sec) == ("=", end.value)
            else:
                assert (e["Oper"], float(e["Value"])) == (end.op.value, end.value)
    _check_rewrite(lambda p: proc.to_file(str(p)), result.path, tmp_path)


def _check_mwf(path: Path, step: ProfileStep, v_min: float, v_max: float) -> None:
    """Read a waveform as BEEP reads its own (tab-separated, no header) and compare with the profile."""
    df = pd.read_csv(path, sep="\t", header=None)
    holds = expand(_holds(step, loops=False))
    assert df.shape == (len(holds), 12)
    sign = np.where(df[0] == "C", 1.0, -1.0)
    np.testing.assert_allclose(sign * df[2], [h.current for h in holds], atol=5e-7)
    np.testing.assert_allclose(df[5], [h.duration for h in holds], atol=5e-5)
    assert set(df[1]) == {"I"} and set(df[9]) == {"T"}
    # charge segments are clamped and ended at the upper voltage, discharge and rest at the lower one
    np.testing.assert_array_equal(df[4], np.where(df[0] == "C", v_max, v_min))
    np.testing.assert_array_equal(df[8], np.where(df[0] == "C", v_max, v_min))
    assert np.sum(sign * df[2] * df[5]) == pytest.approx(step.profile.net_charge * 3600, abs=1e-3)


# --- Arbin ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PROTOCOLS))
def test_beep_reads_arbin_schedules(name: str, tmp_path: Path) -> None:
    proto = _protocol(name, Format.ARBIN)
    result = export(proto, Format.ARBIN, tmp_path)
    sched = Schedule.from_file(str(result.path))["Schedule"]
    n = int(sched["m_uStepNum"])
    steps = [sched[f"Step{i}"] for i in range(n)]
    assert sorted(k for k in sched if k.startswith("Step")) == sorted(f"Step{i}" for i in range(n))
    expected: list[tuple[str, str]] = []  # (control type, value) per schedule step
    for s in proto.steps:
        if isinstance(s, ProfileStep):
            for it in _holds(s, loops=True):
                body = it.body if isinstance(it, Repeat) else (it,)
                hold_steps = [("Rest", "") if h.current == 0 else ("Current(A)", f"{h.current:.6f}") for h in body]
                if isinstance(it, Repeat):
                    expected += [("Set Variable(s)", "65536"), *hold_steps, ("Set Variable(s)", "0")]
                else:
                    expected += hold_steps
        elif isinstance(s, Rest):
            expected.append(("Rest", ""))
        elif isinstance(s, CCCV):
            expected.append(("CCCV", f"{s.current:.6f}"))
        elif isinstance(s, ConstantCurrent):
            expected.append(("Current(A)", f"{s.current:.6f}"))
        else:
            expected.append(("Voltage(V)", f"{s.voltage:.6f}"))
    assert [(st["m_szStepCtrlType"], st["m_szCtrlValue"]) for st in steps] == expected
    # every limit BEEP found is one the step declares, and every step logs at 1 s
    for st in steps:
        limits = [st[f"Limit{j}"] for j in range(int(st["m_uLimitNum"]))]
        assert len(limits) == int(st["m_uLimitNum"]) >= 1
        if st["m_szStepCtrlType"] != "Set Variable(s)":
            assert ("DV_Time", ">=", "1") in [
                (li["Equation0_szLeft"], li["Equation0_szCompareSign"], li["Equation0_szRight"]) for li in limits
            ]
    plain = [s for s in proto.steps if not isinstance(s, ProfileStep)]
    plain_st = [st for st in steps if st["m_szLabel"].split("-", 1)[1].split()[0] in ("rest", "cc", "cccv", "cv")]
    assert len(plain) == len(plain_st)
    left = {"time": "PV_CHAN_Step_Time", "voltage": "PV_CHAN_Voltage"}
    for s, st in zip(plain, plain_st, strict=True):
        limits = [st[f"Limit{j}"] for j in range(int(st["m_uLimitNum"])) if st[f"Limit{j}"]["m_bStepLimit"] == "1"]
        assert len(limits) == len(s.ends)
        charging = s.direction is Direction.CHARGE if isinstance(s, ConstantVoltage) else getattr(s, "current", 0) > 0
        for li, end in zip(limits, s.ends, strict=True):
            side, value = li["Equation0_szLeft"], float(li["Equation0_szRight"])
            if end.quantity.value in left:
                assert (side, value) == (left[end.quantity.value], end.value)
            elif end.quantity.value == "current":
                # the CV current, signed as Arbin measures it (negative on discharge)
                cv_current = "PV_CHAN_CV_Stage_Current" if isinstance(s, CCCV) else "PV_CHAN_Current"
                assert (side, value) == (cv_current, end.value if charging else -end.value)
            else:
                assert side == ("PV_CHAN_Charge_Capacity" if charging else "PV_CHAN_Discharge_Capacity")
                assert value == end.value
        if isinstance(s, CCCV):
            assert float(st["m_szExtCtrlValue1"]) == s.voltage
    lim = proto.limits
    assert sched["m_VoltageSafetyScope"] == f"{lim.voltage_min:.6f}^{lim.voltage_max:.6f}"
    assert sched["m_CurrentSafetyScope"] == f"{-lim.current_max:.6f}^{lim.current_max:.6f}"
    _check_rewrite(lambda p: Schedule.from_file(str(result.path)).to_file(str(p)), result.path, tmp_path)


# --- BioLogic ------------------------------------------------------------------------------------------------


def _sequences(proto: Protocol) -> list[tuple[str, str, str]]:
    """(ctrl_type, ctrl1_val, charge/discharge) of every sequence a faithful .mps holds."""
    from protocols.export.program import split_cccv

    out: list[tuple[str, str, str]] = []
    for s in split_cccv(proto).steps:
        if isinstance(s, ProfileStep):
            for it in _holds(s, loops=True):
                body = it.body if isinstance(it, Repeat) else (it,)
                for h in body:
                    if h.current == 0:
                        out.append(("Rest", "", "Charge"))
                    else:
                        out.append(("CC", f"{abs(h.current) * 1e3:.3f}", "Charge" if h.current > 0 else "Discharge"))
                if isinstance(it, Repeat):
                    out.append(("Loop", "", "Charge"))
        elif isinstance(s, Rest):
            out.append(("Rest", "", "Charge"))
        elif isinstance(s, ConstantCurrent):
            out.append(("CC", f"{abs(s.current) * 1e3:.3f}", "Charge" if s.current > 0 else "Discharge"))
        else:
            side = "Charge" if s.direction is Direction.CHARGE else "Discharge"
            out.append(("CV", f"{s.voltage:.6f}", side))
    return out


@pytest.mark.parametrize("name", list(PROTOCOLS))
def test_beep_reads_biologic_settings(name: str, tmp_path: Path) -> None:
    proto = _protocol(name, Format.BIOLOGIC)
    result = export(proto, Format.BIOLOGIC, tmp_path)
    settings = Settings.from_file(str(result.path))
    technique = settings["Technique"]["1"]
    assert technique["Type"] == "Modulo Bat"
    seqs = list(technique["Step"].values())
    # every row of the technique was read into every sequence; none spilled into the header
    assert all(tuple(seq) == ROWS for seq in seqs)
    assert [int(seq["Ns"]) for seq in seqs] == list(range(len(seqs)))
    assert [(q["ctrl_type"], q["ctrl1_val"], q["charge/discharge"]) for q in seqs] == _sequences(proto)
    for q in seqs:
        if q["ctrl_type"] == "CC":
            assert (q["ctrl1_val_unit"], q["ctrl1_val_vs"]) == ("mA", "<None>")
        if q["ctrl_type"] == "CV":
            assert (q["ctrl1_val_unit"], q["ctrl1_val_vs"]) == ("V", "Ref")
        if q["ctrl_type"] == "Loop":
            assert seqs[int(q["ctrl_seq"])]["ctrl_type"] != "Loop" and int(q["ctrl_repeat"]) >= 1
        assert q["I Range"] == "10 A"
    meta = settings["Metadata"]
    lim = proto.limits
    assert meta["Safety Limits"] == ""
    assert f"\tEcell min = {lim.voltage_min:.6f} V" in meta and f"\tEcell max = {lim.voltage_max:.6f} V" in meta
    assert f"\t|I| max = {lim.current_max:.6f} A" in meta
    assert meta["Comments"] == proto.name
    _check_rewrite(lambda p: settings.to_file(str(p)), result.path, tmp_path)


def test_beep_reads_the_ends_of_biologic_sequences(tmp_path: Path) -> None:
    proto = golden_protocol(Format.BIOLOGIC)
    seqs = list(
        Settings.from_file(str(export(proto, Format.BIOLOGIC, tmp_path).path))["Technique"]["1"]["Step"].values()
    )

    def limits(q: dict) -> list[tuple[str, str, float, str]]:
        n = int(q["lim_nb"])
        return [
            (q[f"lim{j}_type"], q[f"lim{j}_comp"], float(q[f"lim{j}_value"]), q[f"lim{j}_value_unit"])
            for j in range(1, n + 1)
        ]

    plain = [q for q in seqs if q["ctrl_type"] in ("CC", "CV") and q["lim1_type"] != "Time"]
    # the CCCV's CC part to 4.2 V, its CV part to C/50 or 4 h, the C/5 discharge, the CV hold at 3.7 V
    assert [limits(q) for q in plain] == [
        [("Ecell", ">", 4.2, "V")],
        [("|I|", "<", 54.0, "mA"), ("Time", ">", 14400.0, "s")],
        [("Ecell", "<", 2.5, "V"), ("|Q|", ">", 0.27, "A.h")],
        [("|I|", "<", 50.0, "mA"), ("Time", ">", 3600.0, "s")],
    ]
    for q in seqs:
        assert all(q[f"lim{j}_action"] == "Next sequence" for j in (1, 2, 3))


def _check_rewrite(write: Any, ours: Path, tmp_path: Path) -> None:
    """BEEP writes back what it read: the file must be ours, byte for byte."""
    again = tmp_path / "beep-rewrite" / ours.name
    again.parent.mkdir(exist_ok=True)
    write(again)
    assert again.read_bytes() == ours.read_bytes()


def test_beep_reads_the_checked_in_golden_files(golden: Path) -> None:
    """The checked-in golden files (what the docs show a user) are read by BEEP too, not only fresh exports."""
    n_steps = len(golden_protocol(Format.MACCOR).steps)
    assert (
        len(Procedure.from_file(str(golden / "maccor" / "golden.000"))["MaccorTestProcedure"]["ProcSteps"]["TestStep"])
        == n_steps + 1
    )
    sched = Schedule.from_file(str(golden / "arbin" / "golden.sdu"))["Schedule"]
    assert sum(k.startswith("Step") for k in sched) == int(sched["m_uStepNum"])
    seqs = Settings.from_file(str(golden / "biologic" / "golden.mps"))["Technique"]["1"]["Step"]
    assert len(seqs) == len(_sequences(golden_protocol(Format.BIOLOGIC)))
    assert all(tuple(q) == ROWS for q in seqs.values())
