"""Fixtures shared by battlab's tests: logged data from the virtual truth, and reading logs in another process.

The data are pure functions of their arguments (seeded noise): each is simulated once per test session and written
afresh wherever a test asks for it.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest


@functools.cache
def _library() -> Any:
    """The OED input library (built once per session: about 2 s)."""
    from protocols import Library

    return Library.build()


def _frozen(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Read-only copies of the columns (a cached result that no test can change)."""
    out = {k: np.array(v) for k, v in cols.items()}
    for v in out.values():
        v.flags.writeable = False
    return out


@functools.cache
def _virtual_data(pid: int, seed: int) -> tuple[dict[str, np.ndarray], float | None]:
    """The columns of :func:`_virtual_csv` and the profile's start SOC."""
    import battlab
    from battlab import parameters as P
    from battlab.identify.forward import ForwardModel
    from battlab.identify.virtual import synthesize
    from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE

    cell = battlab.Cell.load("nca18650")
    truth = cell.with_values(R_s_n=P.SPECS["R_s_n"].truth, R_s_p=P.SPECS["R_s_p"].truth)
    prof = _library()[pid]
    e = synthesize(ForwardModel(cell), truth, prof, prof.soc0, seed=seed)
    cols = {TIME: prof.t, VOLTAGE: e.voltage, CURRENT: prof.current, AMBIENT: np.full(prof.t.size, 25.0)}
    return _frozen(cols), prof.soc0


def _virtual_csv(tmp_path: Path, pid: int, seed: int) -> str:
    """Library profile ``pid`` on the virtual truth (R_s of both electrodes moved) with seeded noise, logged at
    25 degC as a BDF CSV; its path."""
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import LoggedData

    cols, soc0 = _virtual_data(pid, seed)
    data = LoggedData(f"p{pid}", dict(cols), {"soc0": soc0})
    return str(write_bdf_csv(data, tmp_path / f"p{pid}.bdf.csv"))


@pytest.fixture
def virtual_csv() -> Callable[[Path, int, int], str]:
    """``virtual_csv(tmp_path, pid, seed)``: see :func:`_virtual_csv`."""
    return _virtual_csv


def _c20_cycle() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simulated C/20 discharge, 1 h rest and C/20 charge of nca18650 (isothermal, every 60 s): t [s], I [A]
    (positive = charge), V [V]."""
    import battlab
    from protocols.profile import Profile

    cell = battlab.Cell.load("nca18650")
    i = 2.7 / 20
    ts, cs, vs, t0, soc = [], [], [], 0.0, 1.0
    for cur, dur in [(-i, 21 * 3600.0), (0.0, 3600.0), (i, 21 * 3600.0)]:
        res = battlab.simulate(cell, Profile.constant(cur, dur, 60.0), soc0=soc, isothermal=True, v_limits=(2.5, 4.2))
        ts.append(res.t + t0)
        cs.append(res.current)
        vs.append(res.voltage)
        t0 += res.t[-1] + 60.0
        soc = float(np.clip(soc + cur * res.t[-1] / 3600 / cell.capacity(), 0, 1))
    return np.concatenate(ts), np.concatenate(cs), np.concatenate(vs)


@pytest.fixture(scope="session")
def ocv_csv(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A C/20 OCV test of nca18650 (see :func:`_c20_cycle`, 43 h) logged at 25 degC as a BDF CSV; its path."""
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData

    t, i, v = _c20_cycle()
    cols = {TIME: t, VOLTAGE: v, CURRENT: i, AMBIENT: np.full(t.size, 25.0)}
    return str(write_bdf_csv(LoggedData("c20", cols, {}), tmp_path_factory.mktemp("ocv") / "c20.bdf.csv"))


def _load_in_subprocess(paths: list[Path], timeout_s: float = 60.0) -> list[dict[str, object]]:
    """``battlab.io.data.load_data`` of each path in another process (a hang inside HDF5 holds the GIL, so only a
    process can be timed out): per path ``{"rows": n}`` or ``{"error": type name, "message": text}``."""
    code = textwrap.dedent("""
        import json, sys
        from battlab.io.data import load_data
        for p in sys.argv[1:]:
            try:
                out = {"rows": len(load_data(p))}
            except Exception as exc:
                out = {"error": type(exc).__name__, "message": str(exc)}
            print(json.dumps(out), flush=True)
    """)
    try:
        done = subprocess.run(
            [sys.executable, "-c", code, *map(str, paths)], capture_output=True, text=True, timeout=timeout_s
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"load_data hung: no answer within {timeout_s:g} s (answers so far: {exc.stdout!r})")
    assert done.returncode == 0, done.stderr
    return [json.loads(line) for line in done.stdout.splitlines()]


@pytest.fixture
def load_in_subprocess() -> Callable[..., list[dict[str, object]]]:
    """``load_in_subprocess(paths, timeout_s=60)``: see :func:`_load_in_subprocess`."""
    return _load_in_subprocess


def _run_log(
    path: Path,
    ids: tuple[int, ...] = (28, 37),
    repeat: int = 1,
    truth: bool = True,
    noise: tuple[int, ...] = (),
    trials: int = 0,
    noise_q: float = 0.0,
) -> tuple[Path, Path]:
    """A run log (see :func:`_run_log_data`) written at ``path``, and its plan TOML beside it; (log, plan)."""
    import tomli_w

    from battlab.lab import logfile

    cols, plan = _run_log_data(tuple(ids), repeat, truth, tuple(noise), trials, noise_q)
    w = logfile.create(path, logfile.COLUMNS, {"cell": "nca18650", "plan": json.loads(plan), "soc0": None})
    w.append(dict(cols))
    w.close({"status": "completed"})
    plan_path = path.with_name("plan.toml")
    plan_path.write_text(tomli_w.dumps(json.loads(plan)))
    return path, plan_path


@functools.cache
def _run_log_data(
    ids: tuple[int, ...], repeat: int, truth: bool, noise: tuple[int, ...], trials: int, noise_q: float
) -> tuple[dict[str, np.ndarray], str]:
    """The columns of a run log as the runner writes it (step count and index, trial; the plan in its metadata) of a
    grouped plan of library profiles ``ids`` (profile k in group k), on nca18650 (its R_s moved to Table 4's truth
    when ``truth``), sampled every second: the full charge tapering at 4.2 V, the rests at the OCV of each
    profile's start SOC (SOC 0.8 for 28 and 37), the adjusting steps as ramps, the profiles simulated, with white
    noise of ``noise_q`` [V] (seeded) on the profiles' voltages. ``noise``, ``trials``: the plan starts with
    ``trials`` noise trials of each of these library profiles. Returns (the columns, the plan as JSON)."""
    import battlab
    from battlab import parameters as P
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.io.logged import CYCLE, NET_CAPACITY, STEP, STEP_INDEX
    from battlab.lab import logfile
    from battlab.lab.plan import Plan, RunOptions
    from protocols.protocol import CCCV, ProfileStep, Rest

    cell = battlab.Cell.load("nca18650")
    sim = cell.with_values(R_s_n=P.SPECS["R_s_n"].truth, R_s_p=P.SPECS["R_s_p"].truth) if truth else cell
    lib = _library()
    groups = [(k, [lib[i]]) for k, i in enumerate(ids, start=1)]
    proto = grouped_protocol("loop", groups, "test", ocv_table(cell), [lib[i] for i in noise], trials)
    rng = np.random.default_rng(7)
    plan = Plan(proto, RunOptions(repeat=repeat, stable_hold_s=0.0))
    cols: dict[str, list[np.ndarray]] = {c: [] for c in logfile.COLUMNS}
    t0, soc, q = 0.0, 1.0, 0.0
    for count, entry in enumerate(plan.entries(), start=1):
        s = entry.step
        if isinstance(s, ProfileStep):
            res = battlab.simulate(sim, s.profile, soc0=soc)
            i, v = np.asarray(s.profile.current), np.asarray(res.voltage) + noise_q * rng.standard_normal(res.t.size)
        elif isinstance(s, Rest):
            n = int(s.ends[0].value)
            i, v = np.zeros(n), np.full(n, float(cell.ocv(soc)))
        else:  # charge or discharge towards the next profile's start SOC (0.8): a ramp, ending at rest or tapered
            target = float(s.label.split("SOC ")[1].split()[0])
            v_end = 4.2 if isinstance(s, CCCV) and s.label.startswith("full") else float(cell.ocv(target))
            sign = 1.0 if target >= soc or s.label.startswith("full") else -1.0
            i = sign * np.r_[np.full(100, 1.35), np.linspace(1.35, 0.03, 100)]
            v = np.r_[np.linspace(float(cell.ocv(soc)), v_end, 100), np.full(100, v_end)]
            soc = target if not s.label.startswith("full") else 1.0
        n = i.size
        t = t0 + np.arange(n, dtype=float)
        ah = q + np.concatenate([[0.0], np.cumsum(i[:-1])]) / 3600.0
        if isinstance(s, ProfileStep):
            soc += float(ah[-1] - q) / cell.capacity()
        for c, x in (
            ("Test Time / s", t),
            ("Unix Time / s", 1.7e9 + t),
            ("Step Time / s", t - t0),
            ("Voltage / V", v),
            ("Current / A", i),
            ("Surface Temperature T1 / degC", np.full(n, 25.0)),
            ("Ambient Temperature / degC", np.full(n, 25.0)),
            (STEP, np.full(n, float(count))),
            (STEP_INDEX, np.full(n, float(entry.step_index))),
            (CYCLE, np.full(n, float(entry.trial))),
            (NET_CAPACITY, ah),
        ):
            cols[c].append(x)
        t0, q = float(t[-1]) + 1.0, float(ah[-1])
    return _frozen({c: np.concatenate(v) for c, v in cols.items()}), json.dumps(plan.to_dict())


@pytest.fixture
def run_log() -> Callable[..., tuple[Path, Path]]:
    """``run_log(path, ids=(28, 37), repeat=1, truth=True, noise=(), trials=0, noise_q=0.0)``: see :func:`_run_log`."""
    return _run_log


def _hidden_effect_csv(path: Path, extension: str | None = None, seed: int = 1, **values: float) -> str:
    """UDDS (first 1800 s) from SOC 0.7 at 25 degC on the nominal cell with ``extension`` on at ``values``."""
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import LoggedData

    cols = _hidden_effect_data(extension, seed, tuple(sorted(values.items())))
    return str(write_bdf_csv(LoggedData(path.name.split(".")[0], dict(cols), {"soc0": 0.7}), path))


@functools.cache
def _hidden_effect_data(
    extension: str | None, seed: int, values: tuple[tuple[str, float], ...]
) -> dict[str, np.ndarray]:
    """The columns of :func:`_hidden_effect_csv`."""
    import battlab
    from battlab.identify.forward import ForwardModel
    from battlab.identify.virtual import synthesize
    from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE
    from protocols import Profile
    from protocols.drive_cycles import Cycle, drive_profile

    truth = battlab.Cell.load("nca18650")
    if extension is not None:
        truth = truth.with_extension(extension, **dict(values))
    p = drive_profile(Cycle.UDDS)
    prof = Profile(p.t[:1801], p.current[:1801], id="udds")
    e = synthesize(ForwardModel(truth), truth, prof, 0.7, seed=seed)
    return _frozen({TIME: prof.t, VOLTAGE: e.voltage, CURRENT: prof.current, AMBIENT: np.full(prof.t.size, 25.0)})


@pytest.fixture(scope="session")
def hidden_effect_csv() -> Callable[..., str]:
    """``hidden_effect_csv(path, extension=None, seed=1, **values)``: see :func:`_hidden_effect_csv`."""
    return _hidden_effect_csv


def _stepped_log(path: Path, steps: list[tuple[int, np.ndarray, np.ndarray, float]]) -> Path:
    """A run log (HDF5) of (plan step index, current [A], voltage [V], sample period [s]) steps at 25 degC, 1 ms
    between steps' rows."""
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


@pytest.fixture
def stepped_log() -> Callable[[Path, list[tuple[int, np.ndarray, np.ndarray, float]]], Path]:
    """``stepped_log(path, steps)``: see :func:`_stepped_log`."""
    return _stepped_log


def _prepared_measurement(directory: Path) -> tuple[Path, Path]:
    """(preparation log, measurement log) on nca18650's OCV: a full charge, a rest, 0.54 Ah at C/2 and a 30 min rest
    to SOC 0.8; then a 1-min rest and a 100 s 4 A discharge pulse with 100 s of rest."""
    from battlab.cell import Cell

    cell = Cell.load("nca18650")
    v_full, v08 = float(cell.ocv(0.99)), float(cell.ocv(0.8))
    prep = _stepped_log(
        directory / "48_prep.h5",
        [
            (1, np.full(30, 0.9), np.full(30, 4.2), 10.0),  # the CCCV (its start state is not used)
            (2, np.zeros(60), np.full(60, v_full), 10.0),  # rest after the full charge: the lead-in starts here
            (3, np.full(144, -1.35), np.linspace(4.1, 3.86, 144), 10.0),  # 0.54 Ah at C/2
            (4, np.zeros(180), np.full(180, v08), 10.0),
        ],
    )
    profile = np.r_[np.full(100, -4.0), np.zeros(100)]
    meas = _stepped_log(
        directory / "48.h5",
        [(1, np.zeros(60), np.full(60, v08), 1.0), (2, profile, np.linspace(3.7, 3.9, 200), 1.0)],
    )
    return prep, meas


@pytest.fixture
def prepared_measurement() -> Callable[[Path], tuple[Path, Path]]:
    """``prepared_measurement(directory)`` → (preparation log, measurement log): see :func:`_prepared_measurement`."""
    return _prepared_measurement
