"""A measurement fitted after its logged preparation: the lead-in, the fitted start SOC carried through the stages."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from battlab import Cell, InputError
from battlab.identify import fit as F
from battlab.identify.cumulative import FitSettings, fit_cumulative
from battlab.identify.data_files import load_all
from battlab.identify.fit_options import PREPARED_SOC_SPAN, FitOptions
from battlab.identify.fit_steps import experiments_of


def test_a_prepared_measurement_starts_at_the_full_charge_with_its_preparation_unscored(
    tmp_path: Path, prepared_measurement
) -> None:
    cell = Cell.load("nca18650")
    prep, meas = prepared_measurement(tmp_path)
    dyn, _ = load_all([str(meas)])
    (plain,), _ = experiments_of(FitOptions((str(meas),), "nca18650"), dyn, cell)
    # the preparation named by another spelling of the same path
    other = str(tmp_path / "." / meas.name)
    o = FitOptions((str(meas),), "nca18650", preparations=((other, str(prep)),))
    (e,), files = experiments_of(o, dyn, cell)
    assert plain.lead_in == 0 and e.lead_in > 0 and files == {e.name: meas.stem}
    assert e.mask[: e.lead_in].sum() == 0
    np.testing.assert_allclose(e.scored_voltage, plain.voltage)
    charge = float(np.sum(e.profile.current[: e.lead_in] * np.diff(e.profile.t[: e.lead_in + 1]))) / 3600.0
    assert charge == pytest.approx(-0.54, rel=1e-3)
    assert e.soc0 == pytest.approx(min(1.0, plain.soc0 - charge / cell.capacity()), abs=1e-6)
    assert o.soc_span == PREPARED_SOC_SPAN and FitOptions((str(meas),), "nca18650").soc_span == 0.0


def test_the_lead_in_keeps_the_measurements_own_rest_before_its_profile(tmp_path: Path, prepared_measurement) -> None:
    """A measurement cut from its run log at its profile step (``log_row``): its 60 s rest before the profile
    relaxes the cell after the preparation, so it is part of the lead-in (the preparation's rest after full charge
    to its end, 3830 s, then those 60 s), not skipped."""
    from battlab.identify import runlog
    from battlab.identify.experiments import experiments_from_data
    from battlab.io.data import LoggedData

    cell = Cell.load("nca18650")
    prep, meas = prepared_measurement(tmp_path)
    (log, prep_log), _ = load_all([str(meas), str(prep)])
    sub = LoggedData("48", {c: v[60:] for c, v in log.columns.items()}, dict(log.meta), log.source)
    (cut,) = experiments_from_data(sub, cell, soc0=0.8)
    cut = replace(cut, profile=cut.profile.with_meta(params={**cut.profile.params, "log_row": 60}))
    e = runlog.after_preparation(cut, prep_log, cell, log=log)
    assert e.profile.t[e.lead_in] - e.profile.t[0] == pytest.approx(3830.0 + 60.0, abs=1e-2)
    assert np.all(e.profile.current[e.lead_in - 6 : e.lead_in] == 0.0)  # the rest, in 10 s bins
    assert e.profile.current[e.lead_in] == -4.0 and e.mask[: e.lead_in].sum() == 0
    np.testing.assert_allclose(e.scored_voltage, cut.voltage)
    assert e.soc0 == 1.0
    # without its log the lead-in is the preparation alone
    alone = runlog.after_preparation(cut, prep_log, cell)
    assert alone.profile.t[alone.lead_in] - alone.profile.t[0] == pytest.approx(3830.0, abs=1e-2)


def test_a_preparation_of_no_data_file_or_a_bad_span_is_one_clear_error(tmp_path: Path, prepared_measurement) -> None:
    prep, meas = prepared_measurement(tmp_path)
    with pytest.raises(InputError, match=r"--preparation other\.h5=.*not one of the data files"):
        FitOptions((str(meas),), "nca18650", preparations=(("other.h5", str(prep)),))
    with pytest.raises(InputError, match="soc span 0.7: expected between 0 and 0.5"):
        FitOptions((str(meas),), "nca18650", soc_span=0.7)


def test_each_stage_starts_each_experiment_where_the_last_stage_fitted_its_start_soc(
    tmp_path: Path, prepared_measurement, monkeypatch: pytest.MonkeyPatch
) -> None:
    cell = Cell.load("nca18650")
    prep, meas = prepared_measurement(tmp_path)
    dyn, _ = load_all([str(meas)])
    o = FitOptions((str(meas),), "nca18650", preparations=((str(meas), str(prep)),))
    (e,), _ = experiments_of(o, dyn, cell)
    e = replace(e, soc0=0.97)  # inside the span: the fit may move it both ways
    calls: list[tuple[float, dict, dict[str, float]]] = []
    real = F.fit

    def spy(c: Cell, exps: list, *args: object, **kwargs: object) -> F.FitResult:
        res = real(c, exps, *args, **kwargs)
        calls.append((exps[0].soc0, dict(kwargs.get("soc_start") or {}), dict(res.extra["soc0"])))
        return res

    monkeypatch.setattr(F, "fit", spy)
    stages = [F.Stage(("R_f_n",), (e,)), F.Stage(("R_f_p",), ())]
    fit_cumulative(cell, stages, FitSettings(max_evaluations=3, polish=0, soc_span=o.soc_span))
    (centre1, start1, fitted1), (centre2, start2, fitted2) = calls
    assert centre1 == 0.97 and start1 == {} and abs(fitted1[e.name] - 0.97) <= o.soc_span + 1e-12
    assert fitted1[e.name] != 0.97  # the made-up log's start is not the cell's: the fit moves it
    # stage 2 starts where stage 1 left it, its span still centred on the experiment's own start SOC (no drift)
    assert start2 == {e.name: fitted1[e.name]} and centre2 == 0.97
    assert abs(fitted2[e.name] - 0.97) <= o.soc_span + 1e-12


def test_after_a_full_charge_the_lead_in_starts_at_soc_1_whatever_the_rest_voltage_says(
    tmp_path: Path, stepped_log
) -> None:
    """A CCCV that ends at V_max tapered below C/20 leaves SOC 1 for every model; the measurement's rest voltage
    (here that of SOC 0.7, as a hysteresis branch or a relaxing cell would shift it) does not move it."""
    from battlab.identify import runlog

    cell = Cell.load("nca18650")
    v_max, q = float(cell["V_max"]), float(cell["Q_nom"])
    taper = np.geomspace(q / 3, q / 25, 40)  # the CV step's current down to below C/20
    prep = stepped_log(
        tmp_path / "p.h5",
        [
            (1, taper, np.full(40, v_max - 0.001), 10.0),
            (2, np.zeros(60), np.full(60, float(cell.ocv(0.99))), 10.0),
            (3, np.full(144, -1.35), np.linspace(4.1, 3.86, 144), 10.0),
            (4, np.zeros(180), np.full(180, float(cell.ocv(0.8))), 10.0),
        ],
    )
    meas = stepped_log(
        tmp_path / "m.h5",
        [(1, np.zeros(60), np.full(60, float(cell.ocv(0.7))), 1.0), (2, np.full(50, -2.0), np.full(50, 3.5), 1.0)],
    )
    dyn, _ = load_all([str(meas)])
    (e,), _ = experiments_of(FitOptions((str(meas),), "nca18650"), dyn, cell)
    (prep_log,), _ = load_all([str(prep)])
    assert e.soc0 == pytest.approx(0.7, abs=0.01)
    led = runlog.after_preparation(e, prep_log, cell)
    assert led.soc0 == 1.0 and led.lead_in > 0
    # or where a fit found the same full charge to leave the cell
    assert runlog.after_preparation(e, prep_log, cell, 0.993).soc0 == 0.993
