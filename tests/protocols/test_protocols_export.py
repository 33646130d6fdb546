"""Exporters: golden files, re-import within each format's resolution, and refusals."""

from __future__ import annotations

import shutil
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocols import (
    CCCV,
    ConstantCurrent,
    ConstantVoltage,
    Direction,
    InputError,
    Library,
    Profile,
    ProfileStep,
    Protocol,
    PulseSpec,
    Rest,
    SineSpec,
    concatenate,
    pulse_profile,
    sine_profile,
)
from protocols.export import Format, difference, expected, export, read_back, rules
from protocols.export.program import Repeat, compress, expand

STAMP = datetime(2025, 1, 1, 12, 0, 0)
LOOPING = (Format.ARBIN, Format.BIOLOGIC, Format.NEWARE)


def _demo_profiles() -> tuple[Profile, Profile]:
    pulses = pulse_profile(PulseSpec(2.0, 1, 20.0, Direction.BOTH), charge_ah=0.005, id="pulse-demo", soc0=0.6)
    sine = sine_profile(SineSpec(0.1, 30.0, Direction.BOTH), charge_ah=0.005, id="sine-demo", soc0=0.6)
    return pulses, sine


def golden_protocol(fmt: Format) -> Protocol:
    """A small protocol with every step kind the format supports."""
    pulses, sine = _demo_profiles()
    if fmt is Format.CSV:
        steps = (Rest(("time >= 10",)), ProfileStep(pulses), ProfileStep(sine), Rest(("time >= 10",)))
        return Protocol("golden", steps)
    cv = (
        CCCV(-0.54, 3.7, ("current <= 0.05",), "cccv down")
        if fmt is Format.NEWARE
        else ConstantVoltage(3.7, ("current <= 0.05", "time >= 3600"), Direction.DISCHARGE, "cv down")
    )
    steps = (
        CCCV(1.35, 4.2, ("current <= 0.054", "time >= 14400"), "full charge"),
        Rest(("time >= 600",), "rest"),
        ProfileStep(pulses, "bipolar pulses"),
        ConstantCurrent(-0.54, ("voltage <= 2.5", "capacity >= 0.27"), "C/5 to 10 %"),
        cv,
        ProfileStep(sine, "sine"),
        Rest(("time >= 60",), "rest"),
    )
    return Protocol("golden", steps)


def _tolerances(fmt: Format) -> dict[str, float]:
    r = rules(fmt)
    return {"time_tol": r.time_resolution_s / 2, "current_tol": r.current_resolution_a / 2, "value_tol": 1e-6}


@pytest.mark.parametrize("fmt", list(Format))
def test_golden_files_and_re_import(fmt: Format, tmp_path: Path, golden: Path, regenerate: bool) -> None:
    proto = golden_protocol(fmt)
    result = export(proto, fmt, tmp_path, created=STAMP)
    gdir = golden / fmt.value
    if regenerate:
        shutil.rmtree(gdir, ignore_errors=True)
        gdir.mkdir(parents=True)
        for f in result.files:
            shutil.copy(f, gdir / (f.name + ".txt" if f.suffix == ".py" else f.name))
    written = sorted(f.name for f in result.files)
    kept = sorted(f.name.removesuffix(".txt") for f in gdir.iterdir())
    assert written == kept
    for f in result.files:
        ref = gdir / (f.name + ".txt" if f.suffix == ".py" else f.name)
        assert f.read_bytes() == ref.read_bytes(), f"{f.name} differs from its golden file"
    back = read_back(fmt, result.path)
    assert difference(expected(proto, fmt), back.items, **_tolerances(fmt)) is None
    lim = proto.limits
    if fmt is not Format.CSV:
        assert (back.voltage_min, back.voltage_max) == (lim.voltage_min, lim.voltage_max)
    if fmt in (Format.ARBIN, Format.BIOLOGIC, Format.NEWARE, Format.PYBAMM):
        assert back.current_max == pytest.approx(lim.current_max)
    if fmt in (Format.ARBIN, Format.PYBAMM):
        assert back.temperature_max == pytest.approx(lim.temperature_max)


def test_golden_files_use_loops_where_the_format_has_them(golden: Path) -> None:
    sdu = (golden / "arbin" / "golden.sdu").read_text(encoding="latin-1")
    assert "TC_Counter1" in sdu and "m_szStepCtrlType=Set Variable(s)" in sdu
    mps = (golden / "biologic" / "golden.mps").read_text(encoding="cp1252")
    assert "Loop" in mps
    xml = (golden / "neware" / "golden.xml").read_text()
    assert 'Step_Type="5"' in xml and "Cycle_Count" in xml
    mwf = (golden / "maccor" / "golden_3.MWF").read_text().splitlines()
    assert len(mwf) == 15  # 5 bipolar pulses x (discharge half, charge half, rest), no loops in FastWave


@pytest.mark.parametrize("pid", [1, 57, 100, 339, 540, 541, 650, 720])
@pytest.mark.parametrize("fmt", list(Format))
def test_library_profiles_round_trip(lib: Library, fmt: Format, pid: int, tmp_path: Path) -> None:
    p = lib[pid]
    result = export(p, fmt, tmp_path)
    back = read_back(fmt, result.path)
    assert difference(expected(Protocol.from_profile(p), fmt), back.items, **_tolerances(fmt)) is None
    q = back.profile()
    grid = np.linspace(p.t[0], p.t[-1], 2000, endpoint=False)
    np.testing.assert_allclose(q.value_at(grid), p.value_at(grid), atol=rules(fmt).current_resolution_a)


@pytest.mark.parametrize("fmt", [Format.MACCOR, Format.PYBAMM, Format.CSV])
def test_drive_cycles_export_where_segments_allow(lib: Library, fmt: Format, tmp_path: Path) -> None:
    p = lib[721]
    back = read_back(fmt, export(p, fmt, tmp_path).path)
    assert difference(expected(Protocol.from_profile(p), fmt), back.items, **_tolerances(fmt)) is None


@pytest.mark.parametrize("fmt", LOOPING)
def test_too_many_steps_is_refused_and_nothing_is_written(lib: Library, fmt: Format, tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"needs 21\d\d (steps|sequences) .* more than its 1000; .*--max-steps"):
        export(lib[721], fmt, tmp_path / "out")
    assert not list(tmp_path.iterdir())  # not even the directory
    back = read_back(fmt, export(lib[721], fmt, tmp_path / "more", max_steps=5000).path)
    assert difference(expected(Protocol.from_profile(lib[721]), fmt), back.items, **_tolerances(fmt)) is None


@pytest.mark.parametrize(
    "fmt,hold_s,finest",
    [(Format.MACCOR, 0.005, "0.01 s"), (Format.NEWARE, 0.05, "0.1 s"), (Format.ARBIN, 0.0025, "0.01 s")],
)
def test_timing_finer_than_the_format_is_refused(fmt: Format, hold_s: float, finest: str, tmp_path: Path) -> None:
    p = Profile.from_segments([1.0, hold_s, 1.0], [1.0, -1.0, 0.0], id="fine")
    with pytest.raises(InputError, match=rf"holds -1 A for {hold_s:g} s at t = 1 s, finer than .*{finest}"):
        export(p, fmt, tmp_path)
    assert not list(tmp_path.iterdir())


def test_time_end_finer_than_the_format_is_refused(tmp_path: Path) -> None:
    """Found while writing the procedure: neither a file nor the output directory is left behind."""
    proto = Protocol("fine", (ConstantCurrent(1.0, ("time >= 1.005",)),))
    with pytest.raises(InputError, match=r"step 1 \(cc\): end 'time >= 1.005' is finer than the Maccor"):
        export(proto, Format.MACCOR, tmp_path / "out" / "schedule")
    assert not list(tmp_path.iterdir())


def test_what_a_format_cannot_express_is_refused_naming_the_step(tmp_path: Path) -> None:
    cv = Protocol("p", (Rest(("time >= 1",)), ConstantVoltage(4.0, ("current <= 0.1",))))
    with pytest.raises(InputError, match=r"step 2 \(cv\): Neware .* use a cccv step"):
        export(cv, Format.NEWARE, tmp_path)
    with pytest.raises(InputError, match=r"step 2 \(cv\): a CSV profile holds current vs time only"):
        export(cv, Format.CSV, tmp_path)
    rest_v = Protocol("p", (Rest(("voltage <= 3",)),))
    with pytest.raises(InputError, match=r"step 1 \(rest\): a Neware rest step cannot end on voltage"):
        export(rest_v, Format.NEWARE, tmp_path)
    with pytest.raises(InputError, match=r"step 1 \(rest\): PyBaMM needs a time end"):
        export(rest_v, Format.PYBAMM, tmp_path)
    wrong_side = Protocol("p", (ConstantCurrent(1.0, ("voltage <= 3",)),))
    with pytest.raises(InputError, match="on the other side"):
        export(wrong_side, Format.NEWARE, tmp_path)
    with pytest.raises(InputError, match="unknown export format 'xlsx'"):
        export(cv, "xlsx", tmp_path)


def test_profile_beyond_the_safety_current_is_refused(tmp_path: Path) -> None:
    p = Profile.from_segments([10.0, 10.0], [20.0, 0.0], id="hot")
    with pytest.raises(InputError, match=r"profile hot reaches 20 A, beyond the limit 13.5 A"):
        export(p, Format.ARBIN, tmp_path)


def test_concatenated_plan_exports_to_every_cycler(lib: Library, tmp_path: Path) -> None:
    plan = concatenate([lib[i] for i in (339, 342, 345, 348, 365)], start_soc=0.5).protocol
    for fmt in (Format.MACCOR, Format.ARBIN, Format.BIOLOGIC, Format.NEWARE, Format.PYBAMM):
        back = read_back(fmt, export(plan, fmt, tmp_path / fmt.value).path)
        assert difference(expected(plan, fmt), back.items, **_tolerances(fmt)) is None, fmt


def test_sign_conventions_in_the_files(tmp_path: Path) -> None:
    p = Profile.from_segments([1.0, 1.0], [2.0, -3.0], id="sign")  # charge 2 A, then discharge 3 A
    mwf = export(p, Format.MACCOR, tmp_path / "m").files[1].read_text().splitlines()
    assert mwf[0].split("\t")[:3] == ["C", "I", "2.000000"] and mwf[1].split("\t")[:3] == [
        "D",
        "I",
        "3.000000",
    ]
    sdu = export(p, Format.ARBIN, tmp_path / "a").path.read_text(encoding="latin-1")
    assert "m_szCtrlValue=2.000000" in sdu and "m_szCtrlValue=-3.000000" in sdu
    table = np.loadtxt(_pybamm_table(p, tmp_path), delimiter=",", skiprows=1)
    assert table[0, 1] == -2.0 and table[-1, 1] == 3.0  # PyBaMM: positive = discharge


def _pybamm_table(p: Profile, tmp_path: Path) -> Path:
    files = export(p, Format.PYBAMM, tmp_path / "y").files
    return [f for f in files if f.suffix == ".csv"][0]


@st.composite
def _hold_runs(draw: st.DrawFn) -> list[tuple[float, float]]:
    """Random holds (multiples of 0.1 s, currents to 1 mA) with repeated runs inside."""
    out: list[tuple[float, float]] = []
    for _ in range(draw(st.integers(1, 4))):
        body = draw(st.lists(st.tuples(st.integers(1, 50), st.integers(-13500, 13500)), min_size=1, max_size=4))
        reps = draw(st.integers(1, 5))
        out += [(d / 10, c / 1000) for d, c in body] * reps
    return out


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(holds=_hold_runs(), fmt=st.sampled_from([Format.MACCOR, *LOOPING, Format.CSV]))
def test_random_profiles_round_trip(tmp_path_factory: pytest.TempPathFactory, holds: list, fmt: Format) -> None:
    d = np.array([h[0] for h in holds])
    c = np.array([h[1] for h in holds])
    p = Profile.from_segments(d, c, id="random")
    out = tmp_path_factory.mktemp("rt")
    back = read_back(fmt, export(p, fmt, out).path)
    assert difference(expected(Protocol.from_profile(p), fmt), back.items, **_tolerances(fmt)) is None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 3), st.integers(-2, 2)), min_size=1, max_size=12), st.integers(1, 6))
def test_loop_compression_expands_back_exactly(body: list[tuple[int, int]], reps: int) -> None:
    seq = body * reps
    d = np.array([x[0] for x in seq], dtype=float)
    c = np.array([x[1] for x in seq], dtype=float)
    items = compress(d, c)
    flat = expand(items)
    assert [h.duration for h in flat] == d.tolist() and [h.current for h in flat] == c.tolist()
    steps = sum(len(i.body) + 1 if isinstance(i, Repeat) else 1 for i in items)
    assert steps <= len(seq)


def test_cycler_current_range_is_checked(lib: Library, tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"step 1 \(profile\): needs 12 A, beyond the cycler's 10 A"):
        export(lib[1], Format.MACCOR, tmp_path, max_current_a=10.0)
    assert not list(tmp_path.iterdir())
    export(lib[1], Format.MACCOR, tmp_path, max_current_a=15.0)


def test_biologic_sets_one_fixed_current_range_for_the_safety_current(tmp_path: Path) -> None:
    from protocols import SafetyLimits
    from protocols.export.biologic import read

    steps = (ConstantCurrent(0.05, ("time >= 10",)), Rest(("time >= 10",)), ConstantCurrent(-0.002, ("time >= 5",)))
    for current_max, label, notes in ((0.008, "10 mA", 1), (0.08, "100 mA", 1), (5.0, "10 A", 1), (13.5, "10 A", 2)):
        proto = Protocol("range", steps[2:] if current_max < 0.05 else steps, SafetyLimits(current_max=current_max))
        result = export(proto, Format.BIOLOGIC, tmp_path / label.replace(" ", "") / str(current_max))
        row = next(
            line for line in result.path.read_text(encoding="cp1252").splitlines() if line.startswith("I Range ")
        )
        ranges = {row[i : i + 20].strip() for i in range(20, len(row), 20)}
        assert ranges == {label}, current_max
        assert len(result.notes) == notes and ("I range is 10 A" in result.notes[-1]) == (notes == 2)
        assert read(result.path).current_max == current_max
