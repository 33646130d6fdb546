"""The loop from the command line: a small plan -> `battlab run` against `battlab virtual-tester serve` (the hidden
truth nca18650-true) -> `battlab fit` of the run log from the start cell nca18650."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from battlab.design.plan import grouped_protocol, ocv_table

CLI = [sys.executable, "-c", "from battlab.cli import main; main()"]
_OUT = {"capture_output": True, "text": True}
IDS = (28, 37)  # 600 s discharge pulse trains from SOC 0.8 (30 s and 100 s pulses): SOC 0.8 -> 0.43


@pytest.mark.slow
def test_plan_run_fit_on_the_served_virtual_truth(tmp_path: Path) -> None:
    import battlab
    from protocols import Library

    env = {**os.environ, "BATTLAB_HOME": str(tmp_path / "home"), "PYTHONPATH": str(Path.cwd())}
    lib = Library.build()
    start = battlab.Cell.load("nca18650")
    proto = grouped_protocol("loop", [(1, [lib[i] for i in IDS])], "loop test", ocv_table(start))
    data = proto.to_dict()
    data["run"] = {"stable_hold_s": 0.0}
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps(data))
    # free-running at 400x: at 1000x, on a host shared with another test worker and two benchmarks, the run fell
    # behind the served clock and ended in the cycler's over-temperature trip (alone it passes at 1000x)
    serve = [*CLI, "virtual-tester", "serve", "--cell", "nca18650-true", "--json", "--duration", "600"]
    serve += ["--speed", "400"]
    ports = ["--cycler-port", "0", "--chamber-port", "0", "--espec-port", "0"]
    server = subprocess.Popen([*serve, *ports], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert server.stdout is not None
        urls = json.loads(server.stdout.readline())
        log = tmp_path / "run.h5"
        run = [*CLI, "run", str(plan), "--cycler", urls["cycler"], "--chamber", urls["chamber"], "--quiet"]
        r = subprocess.run([*run, "--cell", "nca18650", "-o", str(log)], capture_output=True, text=True, env=env)
        assert r.returncode == 0, r.stderr
    finally:
        server.terminate()
        server.wait(30)
    out = tmp_path / "fit.bpx.json"
    fit = [*CLI, "fit", str(log), "--cell", "nca18650", "--params", "R_s_n,R_s_p", "--max-iter", "8", "-o", str(out)]
    t0 = time.perf_counter()
    r = subprocess.run(fit, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    assert r.returncode == 0, r.stderr
    s = json.loads(out.with_name("fit.summary.json").read_text())
    stage = s["stages"][-1]
    assert stage["iterations"] <= 8 and stage["cost"] < stage["cost_start"]
    rmse = {k: v for k, v in s["rmse_mV"].items() if k.startswith("run")}  # "run", or "run#k" split at gaps
    print(f"loop: fit {seconds:.1f} s, RMSE {rmse} mV, s2 {stage['s2']:.3g}, {stage['iterations']} evaluations")
    # measured: 45-117 mV per profile from 83-111 mV at the start (two parameters fitted, the truth differs in all
    # 18; the served tester's free-running clock leaves a busy host's samples late, so the numbers vary run to run):
    # the fit improves on its start, it cannot reach noise
    before = {k: v for k, v in s["stages"][0]["rmse_before_mV"].items() if k in rmse}
    assert rmse and before.keys() == rmse.keys() and all(v > 0 for v in rmse.values()), s
    assert sum(rmse.values()) < sum(before.values()), (rmse, before)


def _tester_noise(current: np.ndarray) -> float:
    """The virtual tester's voltage noise [V] under ``current`` [A]: its white and current-dependent parts and the
    quantisation (the jitter part, jitter × dV/dt, left out: it is small between current steps)."""
    from drivers.virtual.noise import NoiseModel

    m = NoiseModel()
    sigma = m.voltage_white_V + m.voltage_per_amp_V * np.abs(current)
    return float(np.sqrt(np.mean(sigma**2) + m.voltage_quantum_V**2 / 12))


@pytest.mark.slow
def test_noise_trials_in_the_plan_give_the_fits_noise_model(tmp_path: Path) -> None:
    """A plan that starts with three noise trials of a discharge pulse train (as `battlab design --noise-trials 3`
    writes them), run on the in-process virtual tester: `battlab fit` finds the trials, fits the noise model from
    them (eq. 36-38) within a factor 1.5 of the tester's noise, says so, and weighs the design's profile by it."""
    import battlab
    from protocols import Library

    env = {**os.environ, "BATTLAB_HOME": str(tmp_path / "home"), "PYTHONPATH": str(Path.cwd())}
    lib = Library.build()
    start = battlab.Cell.load("nca18650")
    proto = grouped_protocol("noise", [(1, [lib[37]])], "noise test", ocv_table(start), [lib[28]], 3)
    data = proto.to_dict()
    data["run"] = {"stable_hold_s": 0.0}
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps(data))
    log = tmp_path / "run.h5"
    run = [*CLI, "run", str(plan), "--cycler", "virtual", "--chamber", "virtual", "--cell", "nca18650-true"]
    r = subprocess.run([*run, "--speed", "1000", "--seed", "3", "--quiet", "-o", str(log)], **_OUT, env=env)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "fit.bpx.json"
    fit = [*CLI, "fit", str(log), "--cell", "nca18650", "--params", "none", "-o", str(out)]
    r = subprocess.run(fit, **_OUT, env=env)
    assert r.returncode == 0, r.stderr
    assert "noise model: fitted to repeated trials (1 profiles, 3 trials" in r.stdout, r.stdout
    s = json.loads(out.with_name("fit.summary.json").read_text())["noise"]
    (trial,) = s["trials"]
    actual = _tester_noise(lib[28].current)
    print(f"noise trials: q {1e6 * trial['q_V']:.0f} uV, tester {1e6 * actual:.0f} uV")
    assert trial["profile"] == "28" and trial["trials"] == 3
    assert actual / 1.5 <= trial["q_V"] <= 1.5 * actual
    from battlab.noise import NoiseModel

    q37 = NoiseModel(**s["model"]).q(lib[37])  # the profile the fit weighs: a discharge like 28
    assert _tester_noise(lib[37].current) / 1.5 <= q37 <= 1.5 * _tester_noise(lib[37].current)
