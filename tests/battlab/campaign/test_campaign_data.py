"""Campaign logs → fit experiments: the measurement with its preparation as lead-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from battlab import Cell, InputError
from battlab.campaign import data as D


def test_a_measurement_starts_with_its_preparation_as_an_unscored_lead_in(tmp_path: Path, prepared_measurement) -> None:
    cell = Cell.load("nca18650")
    prep, meas = prepared_measurement(tmp_path)
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
