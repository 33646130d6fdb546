"""The campaign's OED fit stage and ``battlab fit`` are one engine: on the same run logs, start cell, noise model and
settings they give identical estimates, intervals and convergence."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from battlab import Cell
from battlab.campaign.assessment import fit_oed
from battlab.campaign.config import CampaignConfig, FitSection
from battlab.campaign.context import Campaign
from battlab.campaign.stages import StageContext, StageOutput
from battlab.campaign.tester import Tester
from battlab.cli import main
from battlab.noise import NoiseModel
from protocols import Profile

NAMES = ("R_s_n", "D_s_p")
MAX_EVALUATIONS = 3


def _pulses(pid: str, amp: float) -> Profile:
    durations = np.array([60.0, 60.0, 30.0, 60.0, 60.0, 120.0])
    currents = np.array([-amp, 0.0, 2 * amp, 0.0, -2 * amp, 0.0])
    return Profile.from_segments(durations, currents, id=pid)


@pytest.mark.slow
def test_the_campaign_fit_stage_and_battlab_fit_give_identical_estimates(tmp_path: Path) -> None:
    config = CampaignConfig(fit=FitSection(max_evaluations=MAX_EVALUATIONS, polish=1))
    camp = Campaign(config, Tester(), tmp_path / "camp")
    logs = {}
    for pid, amp in (("11", 2.7), ("12", 1.35)):
        out = camp.run(camp.measurement(_pulses(pid, amp)), f"oed/{pid}")
        assert out.status == "completed", out.reason
        logs[f"log_{pid}"] = str(out.log_path.relative_to(camp.directory))
    cell_path = tmp_path / "start.bpx.json"
    Cell.load("nca18650").to_bpx(cell_path)
    noise_path = tmp_path / "noise.json"
    noise_path.write_text(json.dumps({"model": NoiseModel().__dict__}))
    inputs = {
        "equilibrium": StageOutput({"cell": str(cell_path)}),
        "noise": StageOutput({"model": str(noise_path)}),
        "design": StageOutput(summary={"groups": [{"parameters": list(NAMES), "selected": ["11", "12"]}]}),
        "experiments": StageOutput(logs),
    }
    ctx = StageContext(camp.directory, inputs, lambda *a: None)
    stage = fit_oed(camp)(ctx).summary

    paths = [str(camp.directory / rel) for rel in logs.values()]
    out = tmp_path / "cli" / "cell.bpx.json"
    args = ["fit", *paths, "--cell", str(cell_path), "--params", ",".join(NAMES), "--noise", str(noise_path)]
    r = CliRunner().invoke(main, [*args, "--max-iter", str(MAX_EVALUATIONS), "--polish", "1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    cli = json.loads(out.with_name("summary.json").read_text())

    assert stage["stages"][0]["experiments"] == cli["stages"][0]["experiments"] and len(cli["stages"]) == 1
    for name in NAMES:
        a, b = stage["parameters"][name], cli["parameters"][name]
        assert a["value"] == b["value"] and a["ci95"] == b["ci95"] and a["trusted"] == b["trusted"], name
    assert stage["converged"] == cli["converged"] and stage["s2"] == cli["s2"]
    assert stage["rmse_mV"] == cli["rmse_mV"]
    assert stage["parameters"]["R_s_n"]["value"] != Cell.load("nca18650")["R_s_n"]  # it fitted something
