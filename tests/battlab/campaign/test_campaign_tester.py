"""The campaign's lock-step virtual tester: the run engine on the simulated instruments, in-process, with a clock
that advances only as the physics computes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign import tester as T
from battlab.campaign.tester import VirtualBench, run_plan
from battlab.cell import Cell
from battlab.simulation import simulate
from protocols.profile import Profile


def pulses() -> Profile:
    """30 s at 2C discharge, 30 s rest, 30 s at 1.5C charge, 30 s rest, at 1 s (steps both ways)."""
    i = np.r_[np.full(30, -5.4), np.zeros(30), np.full(30, 4.05), np.zeros(31)]
    return Profile(np.arange(i.size, dtype=float), i, id="pulses", kind="pulse", soc0=0.5)


def test_every_sample_on_time_and_readings_follow_the_true_cell(tmp_path: Path) -> None:
    """A measurement logs every 1 s sample, none late or missing, and its voltage is the true cell's under the
    logged current within the instrument's noise: a reading right after a current step is the step's right limit
    (the sample-time jitter must not add a part of the jump to it)."""
    tester = T.Tester(truth="nca18650-true", seed=3)
    bench = VirtualBench(tester, 25.0)
    prof = pulses()
    out = run_plan(
        P.measurement(prof, 2.7, 25.0, rest_after_s=30.0),
        tester,
        tmp_path / "m.h5",
        cell="nca18650",
        bench=bench,
        soc0=0.5,
    )
    assert out.status == "completed", out.reason
    h = out.health()
    assert h["late_samples"] == 0 and h["gaps"] == 0 and h["samples"] >= 60 + 120 + 30
    d = D.load(out.log_path)
    truth = Cell.load("nca18650-true")
    ref = simulate(truth, Profile(d.t - d.t[0], d.current), soc0=0.5, v_limits=(2.0, 4.6))
    err = d.voltage - ref.voltage
    assert np.max(np.abs(err)) < 2e-3, f"worst reading {1e3 * np.max(np.abs(err)):.2f} mV off the true cell"


def test_the_cell_keeps_its_state_between_runs(tmp_path: Path) -> None:
    """Two runs on one bench: the second starts where the first left the cell (as on a real bench)."""
    from protocols.protocol import ConstantCurrent, Rest, after

    tester = T.Tester(seed=1)
    bench = VirtualBench(tester, 25.0)
    steps = [ConstantCurrent(-2.7, (after(1800.0),), "half an hour at 1C"), Rest((after(600.0),), "rest")]
    first = run_plan(
        P._plan("discharge", steps, 2.7, 10.0, 25.0), tester, tmp_path / "a.h5", cell="nca18650", bench=bench, soc0=0.9
    )
    assert first.status == "completed", first.reason
    second = run_plan(
        P.measurement(pulses(), 2.7, 25.0, rest_after_s=0.0), tester, tmp_path / "b.h5", cell="nca18650", bench=bench
    )
    assert second.status == "completed", second.reason
    a, b = D.load(first.log_path), D.load(second.log_path)
    assert abs(b.voltage[0] - a.voltage[-1]) < 5e-3  # the rest voltage carried over, not a fresh cell
    assert a.voltage[-1] < a.voltage[0] - 0.1  # and the first run did discharge it


def test_a_preparation_that_runs_out_stops_at_its_guard_above_the_abort_limit(tmp_path: Path) -> None:
    """A truth with a stoichiometry-dependent solid diffusivity (b± = 2) cannot give 80 % of its capacity at C/2: the
    preparation to SOC 0.2 reaches the end of what the cell gives, where the voltage falls up to 90 mV per 10 s
    sample. It stops at its guard (V_MIN + PREP_GUARD_V) and completes, instead of passing the 2.45 V abort limit
    between two samples."""
    tester = T.Tester(truth="nca18650-true+solid_diffusion:b_n=2.0,b_p=2.0", seed=0)
    bench = VirtualBench(tester, 25.0)
    out = run_plan(P.prepare(0.2, 2.7, 2.7, 25.0), tester, tmp_path / "p.h5", cell="nca18650", bench=bench, soc0=0.9)
    assert out.status == "completed", out.reason
    d = D.load(out.log_path)
    v = d.voltage[D.steps(d, 3, 3)]
    assert P.V_MIN + 0.05 < v[-1] <= P.V_MIN + P.PREP_GUARD_V  # the guard ended it, not the Ah
