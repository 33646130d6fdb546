"""Logged data → fit experiments: the ambient is measured or given, never guessed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from battlab import Cell, InputError
from battlab.identify.experiments import experiments_from_data
from battlab.io.data import load_data
from protocols.profile import Profile


def test_panasonic_cold_tests_without_a_chamber_reading_need_the_ambient(shared_data: Path, tmp_path: Path) -> None:
    """The 0 °C HWFET file has an empty chamber column: its ambient is the file name's (said), a given value wins;
    the same file under a name without a temperature is refused with the reason, or taken at the given value."""
    import shutil
    import warnings

    src = shared_data / "panasonic-18650pf" / "0degC_HWFET.mat"
    cell = Cell.load("nca18650").with_values(Q_nom=2.9)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        named = load_data(src)
    assert any("Chamber_Temp_degC is not logged" in str(w.message) for w in caught)
    assert all(e.ambient == pytest.approx(273.15) for e in experiments_from_data(named, cell, soc0=0.9))
    bare = shutil.copy(src, tmp_path / "HWFET.mat")
    data = load_data(bare)
    with pytest.raises(InputError, match=r"HWFET\.mat: no ambient temperature logged \(column 'Ambient"):
        experiments_from_data(data, cell, soc0=0.9)
    exps = experiments_from_data(data, cell, soc0=0.9, ambient=273.15)
    assert exps and all(e.ambient == 273.15 for e in exps)
    with pytest.raises(InputError, match="not a temperature in kelvin"):
        experiments_from_data(data, cell, soc0=0.9, ambient=0.0)


def _stepped_log(first: str) -> object:
    """A run log's shape: step 1 a charge tapering at 4.2 V ("cccv") or a 100 s discharge at 1 A ("rest"), step 2
    a rest (600 s at 4.19 V, or 1 h at the OCV of SOC 0.6), step 3 a 300 s discharge at 1 A; and the number of
    samples before the start state is known (after step 1, or after the long rest)."""
    import numpy as np

    from battlab.io.data import AMBIENT, CURRENT, STEP, TIME, VOLTAGE, LoggedData

    cell = Cell.load("nca18650")
    if first == "cccv":
        i1 = np.r_[np.full(100, 1.35), np.linspace(1.35, 0.03, 100)]
        v1 = np.r_[np.linspace(3.9, 4.2, 100), np.full(100, 4.2)]
        n_rest, v_rest = 600, 4.19
    else:
        i1, v1 = np.full(100, -1.0), np.linspace(3.8, 3.7, 100)
        n_rest, v_rest = 3600, float(cell.ocv(0.6))
    i = np.r_[i1, np.zeros(n_rest), np.full(300, -1.0)]
    v = np.r_[v1, np.full(n_rest, v_rest), np.linspace(v_rest - 0.1, v_rest - 0.2, 300)]
    step = np.r_[np.ones(i1.size), np.full(n_rest, 2.0), np.full(300, 3.0)]
    t = np.arange(i.size, dtype=float)
    cols = {TIME: t, VOLTAGE: v, CURRENT: i, AMBIENT: np.full(t.size, 25.0), STEP: step}
    return LoggedData("run", cols, {"soc0": None}), i1.size + (0 if first == "cccv" else n_rest)


@pytest.mark.parametrize(("first", "soc0"), [("cccv", 1.0), ("rest", 0.6)])
def test_a_run_log_starts_from_its_logged_charge_or_rest(first: str, soc0: float) -> None:
    """A run log begins with the plan's CCCV (current flows at its first sample): the start state is the end of
    that charge (SOC 1), or of a long rest (the SOC of its last voltage), not an error asking for --soc0."""
    data, n_first = _stepped_log(first)
    (e,) = experiments_from_data(data, Cell.load("nca18650"))
    assert e.soc0 == pytest.approx(soc0, abs=1e-6)
    assert e.voltage.size == len(data) - n_first  # from the first sample after that step
    assert e.voltage[0] == pytest.approx(data.voltage[n_first])


def test_a_log_without_a_state_setting_step_still_needs_the_start_soc() -> None:
    import numpy as np

    from battlab.io.data import CURRENT, STEP, LoggedData

    data, _ = _stepped_log("cccv")
    cols = dict(data.columns)
    cols[CURRENT] = np.where(cols[STEP] == 1, 1.35, cols[CURRENT])  # no taper: the charge did not end full
    with pytest.raises(InputError, match="give the start SOC"):
        experiments_from_data(LoggedData("run", cols, {}), Cell.load("nca18650"))


@pytest.mark.parametrize(("rest_s", "low", "high"), [(1800.0, 5e-4, 1.2e-3), (7200.0, 0.0, 1.5e-4)])
def test_the_uniform_start_after_a_rest_is_as_good_as_the_rest_is_long(rest_s: float, low: float, high: float) -> None:
    """The fit starts a profile from rest at the SOC of the rest's last voltage, uniform inside the particles. On
    the true cell (τ_n = R_s²/D_s ≈ 4.3 h) after a 0.2-SOC discharge at C/2, 30 min of rest leave 0.79 mV RMS of
    start-state error over the 600 s sine 541 that follows (noise-free; the virtual tester's noise there is about
    0.19 mV), 2 h 0.08 mV: why `battlab design --rest-before` exists."""
    from battlab import Cell, parameters
    from battlab.identify.forward import ForwardModel
    from protocols import Library

    truth = Cell.load("nca18650-true")
    fm = ForwardModel(truth, v_margin=0.15)
    th = np.array([truth.normalised(n) for n in parameters.NAMES])
    p = Library.build()[541]
    n_cc = int(0.2 * truth.capacity() * 3600 / 1.35)
    current = np.concatenate([np.full(n_cc, -1.35), np.zeros(int(rest_s)), p.current])
    chain = fm.run(th, Profile(np.arange(current.size, dtype=float), current), 1.0, ambient=298.15, T0=298.15)
    k0 = n_cc + int(rest_s)
    soc = truth.soc_from_voltage(float(chain.voltage[k0 - 1]))
    alone = fm.run(th, p, soc, ambient=298.15, T0=298.15)
    err = chain.voltage[k0 : k0 + alone.voltage.size] - alone.voltage
    assert low <= float(np.sqrt(np.mean(err**2))) <= high


def test_gaps_are_judged_against_the_datas_own_sampling() -> None:
    """A log sampled every 60 s (± 12 ms, as the Panasonic C/20 test) is one segment until a 3 h pause; a 1 s log
    is cut at a 61 s pause; segments under 10 samples are dropped."""
    from battlab.identify.experiments import segments
    from battlab.io.checks import gap_threshold
    from battlab.io.data import CURRENT, TIME, VOLTAGE, LoggedData

    def log(t: np.ndarray) -> LoggedData:
        return LoggedData("x", {TIME: t, VOLTAGE: np.full(t.size, 3.7), CURRENT: np.zeros(t.size)}, {})

    jitter = np.random.default_rng(0).uniform(-0.012, 0.012, 200)
    slow = np.cumsum(60.0 + jitter)
    slow[150:] += 3 * 3600.0
    assert gap_threshold(slow) == pytest.approx(20 * 60.0, rel=1e-3)
    assert [(s.start, s.stop) for s in segments(log(slow))] == [(0, 150), (150, 200)]
    fast = np.arange(100.0)
    fast[50:] += 60.0  # a 61 s step
    assert gap_threshold(fast) == 60.0
    assert [(s.start, s.stop) for s in segments(log(fast))] == [(0, 50), (50, 100)]
    fast[95:] += 600.0
    assert [(s.start, s.stop) for s in segments(log(fast))] == [(0, 50), (50, 95)]


def test_resampled_voltage_is_the_right_limit_at_a_step_change() -> None:
    """A run log holds the last sample of a rest and the first of the profile 1 ms apart (rest voltage, then the
    loaded one). The grid time where the profile starts carries the profile's current in its bin, so its voltage is
    the loaded one (the model's right limit), not the rest voltage interpolated from the row 1 ms before."""
    from battlab.identify.experiments import resample

    t = np.r_[np.arange(0.0, 61.0), 60.001 + np.arange(0.0, 10.0)]
    current = np.r_[np.zeros(61), np.full(10, -12.0)]
    voltage = np.r_[np.full(61, 3.9669), np.linspace(3.4385, 3.33, 10)]
    tt, ii, vv = resample(t, current, voltage, 1.0)
    assert tt[60] == pytest.approx(60.0)
    assert ii[60] == pytest.approx(-12.0, abs=0.02)  # the bin from 60 s holds the profile's current
    assert vv[60] == pytest.approx(3.4385, abs=1e-3)  # and its voltage is the loaded one
    assert vv[59] == pytest.approx(3.9669)
    assert vv[65] == pytest.approx(np.interp(65.0, t[61:], voltage[61:]))
    # the charge keeps every row: ∫ I dt up to the grid's last time (69 s) equals the log's
    assert np.sum(ii[:-1]) == pytest.approx(-12.0 * (69.0 - 60.001), rel=1e-9)


def test_the_last_resampled_current_is_the_one_logged_with_the_last_voltage() -> None:
    """A 1 s square wave logged 1 ms late on each sample (as a run log's profile step is): the grid's last time has
    no bin of its own, and its current is the row logged there, paired with that row's voltage, not the last
    bin's (which put the final pulse's -12 A against the rest voltage)."""
    from battlab.identify.experiments import resample

    t = 0.001 + np.arange(0.0, 600.0) + 0.001 * (np.arange(600) > 0)
    current = np.where(np.arange(600) % 2 == 0, -12.0, 0.0)
    voltage = np.where(current < 0, 2.75, 3.32)
    tt, ii, vv = resample(t, current, voltage, 1.0)
    loaded = ii < -6.0
    assert loaded.sum() == 300 and np.all(vv[loaded] < 3.0) and np.all(vv[~loaded] > 3.0)
    assert ii[-1] == pytest.approx(0.0, abs=0.02) and vv[-1] == pytest.approx(3.32, abs=1e-3)


def _fixed_rate_drive_log(marked: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 1 Hz drive current logged at 10 Hz, each step 4 ms after a reading (between two readings, as in the
    Panasonic drive tests), on an ohmic cell (3.7 V + 20 mΩ × I): each reading logs the current of its instant.
    ``marked``: the log also holds the left and right limits of every step 1 ms apart (as battlab's run logs do)."""
    steps = np.random.default_rng(3).uniform(-8.0, 4.0, 120)
    t = 0.096 + np.arange(1190) * 0.1
    if marked:
        t = np.sort(np.r_[np.arange(1.1, 119.0) - 0.0005, np.arange(1.1, 119.0) + 0.0005, t])
    current = steps[np.floor(t - 0.1).astype(int) + 1]
    return t, current, 3.7 + 0.02 * current


def test_a_fixed_rate_log_is_read_after_the_step_it_steps_between_readings() -> None:
    """A tester that logs at a fixed rate steps its current between two readings, so the reading at a grid time is
    the left limit of the step there (the bin before's voltage): the voltage is read one logging interval after it,
    and paired with the bin's current it is the ohmic cell's, where the reading at the grid time is off by the
    step's ohmic jump. A log that marks its steps is read at the grid time."""
    from battlab.identify.experiments import read_delay, resample

    t, current, voltage = _fixed_rate_drive_log(marked=False)
    lag = read_delay(t, 1.0)
    assert lag == pytest.approx(0.1)
    tt, ii, vv = resample(t, current, voltage, 1.0, lag)
    inner = slice(1, -2)  # bins whole inside the log
    # within what the ohmic cell makes of a reading's 0.1 s held into the next bin (12 A steps at most)
    assert np.max(np.abs(vv[inner] - (3.7 + 0.02 * ii[inner]))) <= 0.02 * 0.1 * 12.0
    _, _, v_at = resample(t, current, voltage, 1.0)
    assert np.max(np.abs(v_at[inner] - (3.7 + 0.02 * ii[inner]))) > 0.1  # the left limit: off by the jump
    assert read_delay(t, 0.2) == 0.0  # read no faster than a quarter of the grid step: as logged
    marked = _fixed_rate_drive_log(marked=True)
    assert read_delay(marked[0], 1.0) == 0.0


def test_an_experiment_from_a_fixed_rate_log_pairs_each_bins_current_with_its_voltage() -> None:
    """The experiments a fit and a diagnosis take from a fixed-rate log are read after the step, as ``resample``
    with ``read_delay`` reads them."""
    from battlab.io.data import CURRENT, TIME, VOLTAGE, LoggedData

    t, current, voltage = _fixed_rate_drive_log(marked=False)
    data = LoggedData("drive", {TIME: t, VOLTAGE: voltage, CURRENT: current}, {})
    (exp,) = experiments_from_data(data, Cell.load("nca18650"), dt=1.0, soc0=0.9, ambient=298.15)
    ohmic = 3.7 + 0.02 * exp.profile.current[1:-2]
    assert np.max(np.abs(exp.voltage[1:-2] - ohmic)) <= 0.02 * 0.1 * 12.0
