"""The library sensitivity sweep: store contents, 1 s sampling, resume after a kill, staleness, refusal, failures,
local processes and a Dask LocalCluster (battlab.design.sweep, battlab.design.screening)."""

from __future__ import annotations

import logging
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import battlab
from battlab import simulation
from battlab.design import information, sweep
from battlab.design.conventional import CHARGE_C_RATES, DISCHARGE_C_RATES, conventional_profiles
from battlab.design.screening import ModelScreen
from protocols import Library, Profile, standard
from protocols.errors import InputError

NAMES = ("R_s_n", "D_s_p", "R_f_n")  # a few sensitivities keep the tests fast; the full 18 run in the benchmark


def tiny_profiles() -> list[Profile]:
    """Four short profiles: 1 s pulses, 0.5 s edges, a charge, and one that hits 4.2 V at once (flagged)."""
    t = np.arange(121.0)
    pulses = Profile(t, np.where((t // 10) % 2 == 0, -2.7, 0.0), id=1, kind="pulse", soc0=0.5, params={"name": "p"})
    te = np.sort(np.concatenate([np.arange(61.0), np.arange(0.5, 60, 3.0)]))
    edges = Profile(te, np.where((te * 2).astype(int) % 3 == 0, -5.4, 1.0), id=2, kind="pulse", soc0=0.6)
    charge = Profile(np.arange(91.0), np.full(91, 1.35), id=3, kind="sine", soc0=0.4)
    high = Profile(np.arange(31.0), np.full(31, 13.5), id=4, kind="pulse", soc0=0.98)
    return [pulses, edges, charge, high]


CONFIG = sweep.SweepConfig(names=NAMES)
CELL = battlab.Cell.load("nca18650")


def run(path: Path, profiles: list[Profile] | None = None, **kw) -> sweep.SweepReport:
    kw.setdefault("workers", 1)
    return sweep.sweep(profiles or tiny_profiles(), CELL, path, config=CONFIG, progress=False, **kw)


@pytest.fixture(scope="module")
def serial_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sweep") / "serial.h5"
    rep = run(path)
    assert (rep.computed, rep.ok, rep.flagged, rep.failed) == (4, 3, 1, 0)
    return path


def test_store_holds_sensitivities_flags_and_the_1s_factor(serial_store: Path) -> None:
    with sweep.SensitivityStore.open(serial_store) as store:
        assert store.names == NAMES
        assert store.statuses() == {1: "ok", 2: "ok", 3: "ok", 4: "flagged"}
        assert "V > 4.2" in store.info(4)["reason"]
        tr = store.trajectory(2)
        prof = tiny_profiles()[1]
        np.testing.assert_array_equal(tr["t"], prof.t)  # the profile's own samples, half seconds included
        np.testing.assert_array_equal(tr["t"][tr["index_1s"]], np.arange(61.0))
        res = simulation.simulate(CELL, prof, sensitivities=list(NAMES))
        S1 = res.sensitivities[np.isin(res.t, np.arange(61.0))]
        R = store.R(2)
        np.testing.assert_allclose(R.T @ R, S1.T @ S1, rtol=1e-9)
        np.testing.assert_allclose(tr["sens_V"], res.sensitivities, rtol=1e-6, atol=1e-9)  # float32 on disk
        assert tr["sens_T"].shape == tr["sens_V"].shape
        info = information.load(store)
        assert info.ids == (1, 2, 3) and 4 in info.excluded and "flagged" in info.excluded[4]
        F = info.F[1]
        np.testing.assert_allclose(F, S1.T @ S1 / info.q[1] ** 2, rtol=1e-9)


def test_resume_after_kill_9(tmp_path: Path) -> None:
    path = tmp_path / "killed.h5"
    script = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_design_sweep import run, tiny_profiles
        from pathlib import Path
        n = 0
        def die(outcome):
            global n
            n += 1
            if n == 2:
                os.kill(os.getpid(), signal.SIGKILL)
        run(Path({str(path)!r}), on_written=die)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr
    with sweep.SensitivityStore.open(path) as store:
        assert len(store.ids()) == 2
    rep = run(path)
    assert (rep.reused, rep.computed) == (2, 2)
    assert (rep.ok, rep.flagged) == (3, 1)
    rep = run(path)
    assert (rep.reused, rep.computed) == (4, 0)


def test_a_changed_profile_is_recomputed_not_reused(serial_store: Path, tmp_path: Path) -> None:
    path = tmp_path / "stale.h5"
    path.write_bytes(serial_store.read_bytes())
    profs = tiny_profiles()
    profs[0] = Profile(profs[0].t, 0.5 * profs[0].current, id=1, kind="pulse", soc0=0.5)
    rep = run(path, profs)
    assert (rep.reused, rep.computed) == (3, 1)
    with sweep.SensitivityStore.open(path) as store:
        np.testing.assert_allclose(store.profile(1).current, profs[0].current)


def test_store_for_another_cell_or_model_is_refused(serial_store: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    other = battlab.Cell.load("nca18650-true")
    with pytest.raises(InputError, match="holds cell 'nca18650'.*not 'nca18650-true'"):
        sweep.sweep(tiny_profiles(), other, serial_store, config=CONFIG, workers=1, progress=False)
    with pytest.raises(InputError, match="settings differ"):
        sweep.sweep(
            tiny_profiles(), CELL, serial_store, config=sweep.SweepConfig(names=NAMES[:2]), workers=1, progress=False
        )
    monkeypatch.setattr(sweep.keys, "MODEL_VERSION", "dfn-thermal-999")
    with pytest.raises(InputError, match="made by 'battlab .* / dfn-thermal-1'.*stale"):
        sweep.SensitivityStore.open(serial_store)
    with pytest.raises(InputError, match="dfn-thermal-999"):
        run(serial_store)


def test_not_a_store_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "lib.h5"
    Library(tiny_profiles()).save(bad)
    with pytest.raises(InputError, match="not a battlab sensitivity store"):
        sweep.SensitivityStore.open(bad)
    with pytest.raises(InputError, match="no such sensitivity store"):
        sweep.SensitivityStore.open(tmp_path / "missing.h5")


def test_a_failing_profile_is_recorded_and_retried(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = simulation.simulate

    def broken(cell, profile, *a, **kw):  # noqa: ANN001, ANN002, ANN003
        if profile.id == 3:
            raise RuntimeError("solver exploded")
        return real(cell, profile, *a, **kw)

    monkeypatch.setattr(simulation, "simulate", broken)
    path = tmp_path / "fail.h5"
    rep = run(path)
    assert rep.failed == 1 and "solver exploded" in rep.failures[3]
    with sweep.SensitivityStore.open(path) as store:
        assert store.info(3)["status"] == "failed"
        assert 3 in information.load(store).excluded
        with pytest.raises(InputError, match="no sensitivities"):
            store.R(3)
    monkeypatch.setattr(simulation, "simulate", real)
    rep = run(path)
    assert (rep.reused, rep.computed, rep.failed) == (3, 1, 0)


def test_local_processes_and_dask_cluster_match_serial(serial_store: Path, tmp_path: Path) -> None:
    from dask.distributed import LocalCluster

    rep = run(tmp_path / "pool.h5", workers=2)
    assert (rep.ok, rep.flagged) == (3, 1)
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR
    ) as cluster:
        rep = run(tmp_path / "dask.h5", scheduler=cluster.scheduler_address)
    assert (rep.ok, rep.flagged, rep.failed) == (3, 1, 0)
    with (
        sweep.SensitivityStore.open(serial_store) as a,
        sweep.SensitivityStore.open(tmp_path / "pool.h5") as b,
        sweep.SensitivityStore.open(tmp_path / "dask.h5") as c,
    ):
        for pid in (1, 2, 3):
            np.testing.assert_allclose(b.R(pid), a.R(pid), rtol=1e-9, atol=1e-14)
            np.testing.assert_allclose(c.R(pid), a.R(pid), rtol=1e-9, atol=1e-14)


def test_unreachable_scheduler_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
        run(tmp_path / "x.h5", scheduler="tcp://127.0.0.1:9", connect_timeout_s=1.0)


def test_conventional_test_is_cut_at_its_limit_and_rested(tmp_path: Path) -> None:
    cc = Profile(np.arange(4001.0), np.full(4001, -5.4), id="cc_discharge_2C", kind="conventional", soc0=0.2)
    rep = run(tmp_path / "conv.h5", profiles=tiny_profiles()[:1], conventional=[cc], conventional_rest_s=60.0)
    assert rep.ok == 2
    with sweep.SensitivityStore.open(tmp_path / "conv.h5") as store:
        prof = store.simulated_profile("cc_discharge_2C", sweep.CONVENTIONAL)
        on = prof.current[:-1] != 0
        t_cut = prof.t[np.flatnonzero(on)[-1] + 1]
        assert 60 < t_cut < 4000  # stopped at 2.5 V, well before the 4000 s asked
        assert prof.duration == pytest.approx(t_cut + 60.0)
        assert np.all(prof.current[prof.t >= t_cut] == 0)
        conv = information.conventional(store)
        assert conv is not None and conv.ids == ("cc_discharge_2C",)


def test_conventional_profiles_follow_the_protocol() -> None:
    proto = standard.conventional()
    rates = sorted(round(abs(s.current) / 2.7, 6) for s in proto.steps if s.kind.value == "cc" and "C " in s.label)
    ours = conventional_profiles()
    assert sorted(round(abs(float(p.current[0])) / 2.7, 6) for p in ours if p.id.startswith("cc_")) == rates
    assert len(ours) == len(DISCHARGE_C_RATES) + len(CHARGE_C_RATES) + 1
    assert {p.soc0 for p in ours if p.id.startswith("cc_discharge")} == {1.0}


def test_one_second_rows_and_resampling() -> None:
    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    np.testing.assert_array_equal(sweep.one_second_rows(t), [0, 2, 4, 5])
    tt, y = sweep.resample_1s(t, np.arange(6.0))
    np.testing.assert_array_equal(tt, [0, 1, 2, 3])
    np.testing.assert_array_equal(y, [0, 2, 4, 5])
    tt, y = sweep.resample_1s(np.array([0.0, 2.0, 4.0]), np.array([0.0, 2.0, 4.0]))  # no sample at 1 s: interpolate
    np.testing.assert_allclose(y.ravel(), [0, 1, 2, 3, 4])


def test_model_screen_fills_the_library_hook() -> None:
    screen = ModelScreen.for_cell(CELL)
    screen = pickle.loads(pickle.dumps(screen))  # travels to worker processes
    lib = Library(tiny_profiles())
    flags = lib.screen(screen)
    assert flags[1].ok and not flags[4].ok and "V > 4.2" in flags[4].reason
    assert [p.id for p in lib.flagged()] == [4]
