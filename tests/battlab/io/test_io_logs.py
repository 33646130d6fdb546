"""Run log (HDF5, SWMR), BDF CSV, the Panasonic importer and the data checks."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

from battlab.io import load_data, open_log, read_log, run_meta
from battlab.io.bdf import read_bdf_csv, write_bdf_csv
from battlab.io.checks import DataWarning, check_data, detect_sign
from battlab.io.data import CURRENT, TIME, VOLTAGE, LoggedData
from protocols.errors import InputError
from tests.conftest import reference

COLS = [TIME, VOLTAGE, CURRENT, "Surface Temperature T1 / degC", "Step Count / 1"]


def _rows(k0: int, n: int) -> np.ndarray:
    t = np.arange(k0, k0 + n, dtype=float)
    return np.column_stack([t, 3.7 - 1e-4 * t, np.full(n, -2.7), np.full(n, 25.0), np.ones(n)])


def test_log_append_read_while_writing_and_close(tmp_path) -> None:
    path = tmp_path / "run.h5"
    meta = run_meta(cell="nca18650", instruments={"cycler": {"url": "virtual", "idn": "SIM,1"}}, soc0=0.8)
    w = open_log(path, COLS, meta)
    w.append(_rows(0, 100))
    w.flush()
    seen = read_log(path)  # a reader while the writer is open (SWMR)
    assert len(seen) == 100 and not seen.meta["complete"]
    w.append({c: _rows(100, 50)[:, k] for k, c in enumerate(COLS)})
    w.flush()
    assert len(read_log(path)) == 150
    w.close({"status": "completed"})
    data = read_log(path)
    assert list(data.columns) == COLS
    np.testing.assert_array_equal(data.t, np.arange(150.0))
    assert data.meta["cell"] == "nca18650" and data.meta["instruments"]["cycler"]["idn"] == "SIM,1"
    assert data.meta["software"]["battlab"] and data.meta["final"] == {"status": "completed"}
    assert data.meta["complete"]
    assert load_data(path).meta["soc0"] == 0.8


def test_log_rejects_bad_use(tmp_path) -> None:
    with pytest.raises(InputError, match="Current / A"):
        open_log(tmp_path / "a.h5", [TIME, VOLTAGE], {})
    w = open_log(tmp_path / "b.h5", COLS, {})
    with pytest.raises(InputError, match="expected rows of 5 values"):
        w.append(np.zeros((2, 3)))
    with pytest.raises(InputError, match="missing column"):
        w.append({TIME: [0.0]})
    w.close()
    with pytest.raises(InputError, match="never overwritten"):
        open_log(tmp_path / "b.h5", COLS, {})
    with pytest.raises(InputError, match="not JSON"):
        open_log(tmp_path / "c.h5", COLS, {"x": object()})


def test_log_survives_a_killed_writer(tmp_path) -> None:
    path = tmp_path / "killed.h5"
    code = textwrap.dedent(f"""
        import time, numpy as np
        from battlab.io import open_log
        w = open_log({str(path)!r}, {COLS!r}, {{"cell": "x"}})
        for k in range(3):
            t = np.arange(k * 10, k * 10 + 10, dtype=float)
            w.append(np.column_stack([t, t, t, t, t]))
            w.flush()
        print("flushed", flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "flushed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    data = read_log(path)
    assert len(data) == 30 and not data.meta["complete"]
    np.testing.assert_array_equal(data.t, np.arange(30.0))


def _truncated_copies(path, tmp_path) -> list:
    """Copies of ``path`` cut to the superblock alone (48 bytes), to half, and one byte short."""
    data = path.read_bytes()
    out = []
    for name, n in (("sb", 48), ("half", len(data) // 2), ("short", len(data) - 1)):
        cut = tmp_path / f"{path.stem}-{name}.h5"
        cut.write_bytes(data[:n])
        out.append(cut)
    return out


def test_a_truncated_log_is_an_input_error_naming_the_file_not_a_hang(tmp_path, load_in_subprocess) -> None:
    closed = tmp_path / "closed.h5"
    w = open_log(closed, COLS, {"cell": "x"}, chunk_rows=64)
    for k in range(20):
        w.append(_rows(k * 50, 50))
        w.flush()
    w.close({"status": "completed"})
    killed = tmp_path / "killed.h5"
    code = textwrap.dedent(f"""
        import os, numpy as np
        from battlab.io import open_log
        w = open_log({str(killed)!r}, {COLS!r}, {{"cell": "x"}}, chunk_rows=64)
        for k in range(20):
            t = np.arange(k * 50, k * 50 + 50, dtype=float)
            w.append(np.column_stack([t, t, t, t, t]))
            w.flush()
        os.kill(os.getpid(), 9)
    """)
    subprocess.run([sys.executable, "-c", code], timeout=60)
    assert len(read_log(killed)) == 1000 and len(read_log(closed)) == 1000  # the intact files read
    cuts = _truncated_copies(closed, tmp_path) + _truncated_copies(killed, tmp_path)
    for cut, got in zip(cuts, load_in_subprocess(cuts), strict=True):
        assert got.get("error") == "InputError", (cut.name, got)
        assert str(cut) in got["message"] and "\n" not in got["message"]
        assert "truncated" in got["message"] or "not a readable" in got["message"], got["message"]


def test_bdf_csv_round_trip_is_valid_bdf(tmp_path) -> None:
    bdf = reference("bdf")
    data = LoggedData("x", {c: _rows(0, 20)[:, k] for k, c in enumerate(COLS)}, {"soc0": 0.5, "cell": "c"})
    path = write_bdf_csv(data, tmp_path / "x.bdf.csv")
    rep = bdf.validate(str(path))
    assert rep["ok"], rep
    back = read_bdf_csv(path)
    assert back.meta == {"soc0": 0.5, "cell": "c"}
    for c in COLS:
        np.testing.assert_allclose(back.columns[c], data.columns[c])


def test_bdf_csv_errors_name_the_line(tmp_path) -> None:
    p = tmp_path / "bad.bdf.csv"
    p.write_text("Test Time / s,Voltage / V,Current / A\n0,3.7,0\n1,abc,0\n")
    with pytest.raises(InputError, match="line 3.*Voltage / V"):
        read_bdf_csv(p)
    p.write_text("Time,Voltage / V\n0,3.7\n")
    with pytest.raises(InputError, match="missing BDF column"):
        read_bdf_csv(p)


def test_csv_errors_show_the_header_found(tmp_path) -> None:
    """A semicolon-separated file, a short row (read as NaN), a profile CSV or a run log without a column: the
    message shows the header (or columns) the file has."""
    from protocols.profile import Profile

    p = tmp_path / "semi.bdf.csv"
    p.write_text("Test Time / s;Voltage / V;Current / A\n0;3.7;0\n1;3.7;0\n")
    header = "['Test Time / s;Voltage / V;Current / A'] (separated by ';': a BDF CSV is comma-separated)"
    with pytest.raises(InputError, match=re.escape(f"the header has {header}")):
        read_bdf_csv(p)
    p = tmp_path / "short.bdf.csv"
    p.write_text("Test Time / s,Voltage / V,Current / A\n0,3.7,0\n1,3.7\n2,3.7,0\n")
    found = "line 3 of the file, whose header has ['Test Time / s', 'Voltage / V', 'Current / A']"
    with pytest.raises(InputError, match=re.escape(f"'Current / A' is NaN or infinite at sample 1 (t = 1 s); {found}")):
        load_data(p)
    p = tmp_path / "profile.csv"
    p.write_text("Time [s],Current [A]\n0,1\n1,1\n")
    with pytest.raises(InputError, match=re.escape("the header has ['Time [s]', 'Current [A]']")):
        Profile.from_csv(p)
    with pytest.raises(InputError, match=re.escape("found ['Test Time / s', 'Current / A']")):
        LoggedData("x", {TIME: [0.0, 1.0], CURRENT: [0.0, 0.0]}, {}, "x.h5")


def _slow_test() -> LoggedData:
    t = np.arange(0, 2000.0)
    i = np.where(t < 1000, -1.0, 1.0)
    v = np.where(t < 1000, 4.0 - 1e-4 * t, 3.9 + 1e-4 * (t - 1000))
    return LoggedData("slow", {TIME: t, VOLTAGE: v, CURRENT: i}, {}, "slow.csv")


def test_checks_name_file_and_samples() -> None:
    d = _slow_test()
    v = d.voltage.copy()
    v[10:13] = np.nan
    with pytest.raises(InputError, match=r"slow.csv: column 'Voltage / V' is NaN .*samples 10–12 \(t = 10–12 s\)"):
        check_data(LoggedData("slow", {**d.columns, VOLTAGE: v}, {}, "slow.csv"))
    t = d.t.copy()
    t[500] = 10.0
    with pytest.raises(InputError, match="slow.csv: time is not sorted: sample 500"):
        check_data(LoggedData("slow", {**d.columns, TIME: t}, {}, "slow.csv"))
    t = d.t.copy()
    t[1500:] += 5000
    t[100] = t[99]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = check_data(LoggedData("slow", {**d.columns, TIME: t}, {}, "slow.csv"))
    msgs = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    assert any("repeated time stamp" in m and "sample 99" in m for m in msgs)
    assert any("gap" in m and "largest 5001 s" in m for m in msgs), msgs
    assert len(out) == len(d) - 1


def test_sign_convention_detected_from_ocv_direction(shared_data) -> None:
    good = load_data(shared_data / "panasonic-18650pf" / "25degC_C20_OCV.mat")
    assert detect_sign(good.t, good.current, good.voltage)[0] == 1
    flipped = LoggedData("c20", {**good.columns, CURRENT: -good.current}, {}, "c20.mat")
    with pytest.raises(InputError, match="c20.mat: the current's sign looks reversed"):
        check_data(flipped)
    with pytest.warns(DataWarning, match="flipped"):
        fixed = check_data(flipped, fix_sign=True)
    np.testing.assert_array_equal(fixed.current, good.current)
    us06 = load_data(shared_data / "panasonic-18650pf" / "25degC_US06.mat")  # dynamic: ohmic response
    assert detect_sign(us06.t, us06.current, us06.voltage)[0] == 1
    assert detect_sign(us06.t, -us06.current, us06.voltage)[0] == -1


def test_panasonic_import(shared_data) -> None:
    with pytest.warns(DataWarning, match="repeated time stamp"):
        d = load_data(shared_data / "panasonic-18650pf" / "25degC_HPPC.mat")
    assert d.meta["rated_capacity_Ah"] == 2.9
    assert np.all(np.diff(d.t) > 0)
    assert d.current.min() < -15 and d.current.max() <= 0  # discharge pulses, positive = charge
    assert "Surface Temperature T1 / degC" in d.columns and "Net Capacity / Ah" in d.columns


def test_unknown_suffix_and_missing_file(tmp_path) -> None:
    with pytest.raises(InputError, match="no such data file"):
        load_data(tmp_path / "nope.h5")
    p = tmp_path / "x.txt"
    p.write_text("hi")
    with pytest.raises(InputError, match="unknown data format"):
        load_data(p)
    bad = tmp_path / "bad.mat"
    bad.write_text("not matlab")
    with pytest.raises(InputError, match="bad.mat: not a readable MATLAB"):
        load_data(bad)
