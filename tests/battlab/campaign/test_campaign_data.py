"""Campaign logs → fit experiments: the measurement with its preparation as lead-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from battlab import Cell, InputError
from battlab.campaign import data as D


def _log(path: Path, steps: list[tuple[int, np.ndarray, np.ndarray, float]]) -> Path:
    """A run log of (step index, current [A], voltage [V], sample period [s]) steps, 1 ms between steps' rows."""
    from battlab.io.logged import CYCLE, NET_CAPACITY, STEP, STEP_INDEX
    from battlab.lab import logfile

    cols: dict[str, list[np.ndarray]] = {c: [] for c in logfile.COLUMNS}
    t0, q = 0.0, 0.0
    for k, (index, i, v, dt) in enumerate(steps, start=1):
        t = t0 + dt * np.arange(i.size)
        ah = q + np.concatenate([[0.0], np.cumsum(i[:-1] * dt)]) / 3600.0
        for c, x in (
            ("Test Time / s", t),
            ("Unix Time / s", 1.7e9 + t),
            ("Step Time / s", t - t0),
            ("Voltage / V", v),
            ("Current / A", i),
            ("Surface Temperature T1 / degC", np.full(i.size, 25.0)),
            ("Ambient Temperature / degC", np.full(i.size, 25.0)),
            (STEP, np.full(i.size, float(k))),
            (STEP_INDEX, np.full(i.size, float(index))),
            (CYCLE, np.ones(i.size)),
            (NET_CAPACITY, ah),
        ):
            cols[c].append(x)
        t0, q = float(t[-1]) + dt + 1e-3, float(ah[-1] + i[-1] * dt / 3600.0)
    w = logfile.create(path, logfile.COLUMNS, {"cell": "nca18650", "soc0": None})
    w.append({c: np.concatenate(v) for c, v in cols.items()})
    w.close({"status": "completed"})
    return path


def test_a_measurement_starts_with_its_preparation_as_an_unscored_lead_in(tmp_path: Path) -> None:
    cell = Cell.load("nca18650")
    v_full, v08 = float(cell.ocv(0.99)), float(cell.ocv(0.8))
    prep = _log(
        tmp_path / "48_prep.h5",
        [
            (1, np.full(30, 0.9), np.full(30, 4.2), 10.0),  # the CCCV (its start state is not used)
            (2, np.zeros(60), np.full(60, v_full), 10.0),  # rest after the full charge: the lead-in starts here
            (3, np.full(144, -1.35), np.linspace(4.1, 3.86, 144), 10.0),  # 0.54 Ah at C/2
            (4, np.zeros(180), np.full(180, v08), 10.0),
        ],
    )
    profile = np.r_[np.full(100, -4.0), np.zeros(100)]
    meas = _log(
        tmp_path / "48.h5", [(1, np.zeros(60), np.full(60, v08), 1.0), (2, profile, np.linspace(3.7, 3.9, 200), 1.0)]
    )
    plain = D.experiment(meas, cell, name="profile 48")
    e = D.experiment_after_preparation(prep, meas, cell, name="profile 48")
    assert e.lead_in > 0 and e.mask[: e.lead_in].sum() == 0 and e.mask[e.lead_in :].all()
    np.testing.assert_allclose(e.scored_voltage, plain.voltage)
    np.testing.assert_allclose(e.profile.current[e.lead_in :], plain.profile.current)
    # from the rest after the full charge: 60 rows of rest, then the 0.54 Ah adjustment and the 30 min rest
    lead_t = e.profile.t[e.lead_in] - e.profile.t[0]
    assert lead_t == pytest.approx(600.0 + 1440.0 + 1800.0, abs=11.0)
    charge = float(np.sum(e.profile.current[: e.lead_in] * np.diff(e.profile.t[: e.lead_in + 1]))) / 3600.0
    assert charge == pytest.approx(-1.35 * 1440.0 / 3600.0, rel=1e-3)
    assert e.soc0 == pytest.approx(plain.soc0 - charge / cell.capacity(), abs=1e-4)
    with pytest.raises(InputError, match="no rest after a full charge"):
        D.experiment_after_preparation(meas, meas, cell, name="profile 48")
