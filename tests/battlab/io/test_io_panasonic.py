"""The Panasonic 18650PF importer puts back the pauses that ``Time`` runs across and ``TimeStamp`` shows."""

from __future__ import annotations

import datetime as dt
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from battlab.io.checks import DataWarning
from battlab.io.logged import CURRENT, NET_CAPACITY, TIME, VOLTAGE
from battlab.io.panasonic import read_panasonic, wall_clock_s

FILES = sorted(f"{deg}degC_{test}.mat" for deg in (0, 10, 25) for test in ("HPPC", "HWFET", "US06")) + [
    "25degC_C20_OCV.mat"
]


def _stamp(when: dt.datetime) -> str:
    """MATLAB datestr's text, which leaves out the time of day at midnight."""
    if when.hour == when.minute == when.second == 0:
        return f"{when.month}/{when.day}/{when.year}"
    return f"{when.month}/{when.day}/{when.year} {when.strftime('%I:%M:%S %p').lstrip('0')}"


def _write(path: Path, fields: dict[str, np.ndarray], stamps: list[str]) -> Path:
    meas = {k: np.asarray(v, float).reshape(-1, 1) for k, v in fields.items()}
    meas["TimeStamp"] = np.array(stamps, dtype=object).reshape(-1, 1)
    scipy.io.savemat(path, {"meas": meas})
    return path


def _pause_warnings(caught: list[warnings.WarningMessage]) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, DataWarning) and "TimeStamp" in str(w.message)]


def test_a_synthetic_pause_becomes_a_rest_and_time_follows_the_wall_clock(tmp_path: Path) -> None:
    """1 s samples at -1 A; after sample 99 the wall clock jumps 2 h while Time steps 1 s; sample 200 is stamped
    at midnight (date only, as MATLAB writes it)."""
    n, k, pause = 300, 99, 7200.0
    t = np.arange(n, dtype=float)
    wall = t + np.where(np.arange(n) > k, pause, 0.0)
    start = dt.datetime(2017, 6, 1, 21, 56, 40)
    stamps = [_stamp(start + dt.timedelta(seconds=float(w))) for w in wall]
    assert stamps[200] == "6/2/2017"
    current = np.full(n, -1.0)
    ah = np.concatenate([[0.0], np.cumsum(current[:-1] * np.diff(t))]) / 3600
    voltage = 3.9 - 0.001 * t
    path = _write(tmp_path / "paused.mat", {"Time": t, "Voltage": voltage, "Current": current, "Ah": ah}, stamps)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    (msg,) = _pause_warnings(caught)
    assert str(path) in msg and "after sample 99" in msg and "7200 s (2.00 h)" in msg, msg
    assert "9:58:19 PM -> 6/1/2017 11:58:20 PM" in msg, msg
    assert len(d) == n + 1
    assert np.all(np.diff(d.t) > 0)
    assert d.t[-1] - d.t[0] == pytest.approx(wall[-1] - wall[0])  # time follows the wall clock
    assert d.t[k + 1] == 100.0 and d.current[k + 1] == 0.0  # the rest starts after sample 99's 1 s step
    assert d.t[k + 2] == 100.0 + pause and d.voltage[k + 2] == voltage[k + 1]
    # the rest moves no charge: the held current integrates to the logged Ah
    assert np.sum(d.current[:-1] * np.diff(d.t)) / 3600 == pytest.approx(ah[-1])
    assert d.columns[NET_CAPACITY][k + 1] == ah[k + 1]
    assert d.meta["pauses"] == [{"after_sample": 99, "t_s": 100.0, "duration_s": pause}]


def test_no_pause_no_change(tmp_path: Path) -> None:
    """A gap in both Time and TimeStamp (as HPPC files skip the discharges) is not a pause."""
    t = np.r_[np.arange(100.0), 3700.0 + np.arange(100.0)]
    start = dt.datetime(2017, 3, 11, 10, 0, 0)
    stamps = [_stamp(start + dt.timedelta(seconds=float(s))) for s in t]
    path = _write(
        tmp_path / "gap.mat", {"Time": t, "Voltage": np.full(t.size, 3.7), "Current": -np.ones(t.size)}, stamps
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    assert _pause_warnings(caught) == [] and len(d) == t.size and np.array_equal(d.t, t) and "pauses" not in d.meta


@pytest.fixture(scope="module")
def us06(shared_data: Path) -> dict[str, np.ndarray]:
    raw = scipy.io.loadmat(
        shared_data / "panasonic-18650pf" / "25degC_US06.mat", squeeze_me=True, struct_as_record=False
    )
    m = raw["meas"]
    return {f: np.atleast_1d(getattr(m, f)) for f in m._fieldnames}


def test_a_pause_put_into_a_real_file_is_found_where_and_how_long(tmp_path: Path, us06: dict[str, np.ndarray]) -> None:
    """The real 25 degC US06 file (its first 20 000 samples) with its wall clock moved 3 h on after sample 10 000
    (Time untouched)."""
    k, pause = 10000, 3 * 3600.0
    us06 = {f: v[:20000] for f, v in us06.items()}
    wall = wall_clock_s(us06["TimeStamp"])
    start = dt.datetime.strptime(str(us06["TimeStamp"][0]), "%m/%d/%Y %I:%M:%S %p")
    moved = wall + np.where(np.arange(wall.size) > k, pause, 0.0)
    stamps = [_stamp(start + dt.timedelta(seconds=float(w))) for w in moved]
    fields = {f: v for f, v in us06.items() if f != "TimeStamp"}
    path = _write(tmp_path / "25degC_US06_paused.mat", fields, stamps)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    (msg,) = _pause_warnings(caught)
    assert "25degC_US06_paused.mat" in msg and f"after sample {k}" in msg, msg
    (p,) = d.meta["pauses"]
    assert p["after_sample"] == k and p["duration_s"] == pytest.approx(pause, abs=2.0)  # 1 s stamps
    t = us06["Time"]
    assert len(d) == t.size + 1 and d.current[k + 1] == 0.0 and np.all(np.diff(d.t) >= 0)
    assert d.t[-1] - d.t[0] == pytest.approx(t[-1] - t[0] + p["duration_s"])
    assert np.array_equal(d.voltage[k + 2 :], us06["Voltage"][k + 1 :])


@pytest.mark.parametrize("name", FILES)
def test_the_shipped_files_have_no_pause(shared_data: Path, name: str) -> None:
    """Scanned: in none of the ten shipped files does TimeStamp run ahead of Time (the largest excess of one step
    is 1 s, the stamps' resolution; the HPPC files' hour-long gaps are in both columns)."""
    path = shared_data / "panasonic-18650pf" / name
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    assert _pause_warnings(caught) == [] and "pauses" not in d.meta
    assert d.columns[TIME].size == d.columns[VOLTAGE].size == d.columns[CURRENT].size


def _slow_test(tmp_path: Path, offset: float, name: str = "25degC_C20_OCV.mat") -> Path:
    """A C/20-like test: rest, discharge at 0.145 A for 18 h, rest, charge back the same charge at 0.145 A, with the
    logged current read ``offset`` [A] off while it flows."""
    t = np.arange(0.0, 40 * 3600.0, 60.0)
    i = np.zeros(t.size)
    dis = (t >= 600) & (t < 600 + 18 * 3600)
    chg = (t >= 19 * 3600) & (t < 37 * 3600)
    i[dis], i[chg] = -0.145, 0.145
    v = 3.7 + 0.4 * np.cumsum(i * 60.0) / (0.145 * 18 * 3600)
    logged = np.where(i != 0, i + offset, 0.0)
    start = dt.datetime(2017, 5, 8, 13, 0, 0)
    stamps = [_stamp(start + dt.timedelta(seconds=float(s))) for s in t]
    fields = {"Time": t, "Voltage": v, "Current": logged, "Ah": np.cumsum(logged * 60.0) / 3600.0}
    fields |= {"Battery_Temp_degC": np.full(t.size, 25.0), "Chamber_Temp_degC": np.full(t.size, 25.0)}
    return _write(tmp_path / name, fields, stamps)


def test_a_slow_tests_current_offset_is_found_and_said_not_corrected(tmp_path: Path) -> None:
    from battlab.io.panasonic import with_current_offset

    path = _slow_test(tmp_path, -0.008)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    said = [str(w.message) for w in caught if "current offset" in str(w.message)]
    assert len(said) == 1 and "current offset of -8." in said[0]
    assert d.meta["current_offset_A"] == pytest.approx(0.008, rel=0.03)
    assert np.min(d.columns[CURRENT]) == pytest.approx(-0.153)  # as logged
    fixed = with_current_offset(d, d.meta["current_offset_A"])
    assert np.min(fixed.columns[CURRENT]) == pytest.approx(-0.145, abs=2e-4)
    assert fixed.columns[NET_CAPACITY][-1] == pytest.approx(0.0, abs=5e-3)  # was -0.29 Ah


def test_a_balanced_slow_test_says_nothing(tmp_path: Path) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(_slow_test(tmp_path, 0.0))
    assert not [w for w in caught if "current offset" in str(w.message)]
    assert "current_offset_A" not in d.meta


def test_a_chamber_column_far_from_the_file_names_temperature_is_said_and_dropped(tmp_path: Path) -> None:
    from battlab.io.logged import AMBIENT

    path = _slow_test(tmp_path, 0.0, name="10degC_C20_OCV.mat")  # logs 25 degC in a 10 degC test
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = read_panasonic(path)
    said = [str(w.message) for w in caught if "Chamber_Temp_degC" in str(w.message)]
    assert len(said) == 1 and "reads 25 degC" in said[0] and "10 degC" in said[0]
    assert AMBIENT not in d.columns
    assert d.ambient_K() == pytest.approx(283.15)


def test_the_shared_c20_test_has_a_current_offset_of_about_10_mA(shared_data: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = read_panasonic(shared_data / "panasonic-18650pf" / "25degC_C20_OCV.mat")
    assert 0.008 < d.meta["current_offset_A"] < 0.012
