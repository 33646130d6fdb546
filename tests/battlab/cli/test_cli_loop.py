"""The loop from the command line: a small plan -> `battlab run` against `battlab virtual-tester serve` (the hidden
truth nca18650-true) -> `battlab fit` of the run log from the start cell nca18650."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

from battlab.design.plan import grouped_protocol, ocv_table

CLI = [sys.executable, "-c", "from battlab.cli import main; main()"]
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
    serve = [*CLI, "virtual-tester", "serve", "--cell", "nca18650-true", "--json", "--duration", "600"]
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
