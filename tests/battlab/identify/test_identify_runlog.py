"""A run log is fitted on its plan's structure: one experiment per executed profile step, tagged with its library
id, so that the design's groups become the fit's stages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from battlab import Cell, InputError
from battlab.identify import runlog, workflow
from battlab.io.data import load_data


def test_a_run_log_is_cut_at_its_profile_steps(tmp_path: Path, run_log) -> None:
    log, _ = run_log(tmp_path / "run.h5")
    data = load_data(log)
    exps = runlog.experiments(data, Cell.load("nca18650"))
    assert [e.name for e in exps] == ["run:28", "run:37"]
    assert [e.profile.params["library_id"] for e in exps] == ["28", "37"]
    for e in exps:  # the 600 s profile alone, from the SOC of the rest before it
        assert e.soc0 == pytest.approx(0.8, abs=1e-3)
        assert e.profile.duration == pytest.approx(600.0, abs=1.0)
    groups = runlog.logged_groups([data])
    stages = workflow.stages(None, None, exps, [(g.parameters, set(g.selected)) for g in groups])
    assert [[e.name for e in s.experiments] for s in stages[:2]] == [["run:28"], ["run:37"]]
    assert stages[0].names == ("R_s_n", "R_s_p")  # labels 'group k' with Table 9's groups


def test_repeated_profiles_are_one_experiment_per_trial(tmp_path: Path, run_log) -> None:
    log, _ = run_log(tmp_path / "run.h5", ids=(28,), repeat=2)
    exps = runlog.experiments(load_data(log), Cell.load("nca18650"))
    assert [e.name for e in exps] == ["run:28t1", "run:28t2"]
    assert [e.profile.params["trial"] for e in exps] == [1, 2]


def test_the_given_plan_must_be_the_one_that_ran(tmp_path: Path, run_log) -> None:
    from battlab.io.plan import Plan

    log, _ = run_log(tmp_path / "run.h5")
    (tmp_path / "other").mkdir()
    _, other = run_log(tmp_path / "other" / "run.h5", ids=(37, 28))
    with pytest.raises(InputError, match=r"run\.h5: the run's plan is not .*step 5 runs profile 28 in the log"):
        runlog.experiments(load_data(log), Cell.load("nca18650"), plan=Plan.load(other), plan_name=str(other))


def test_the_runner_keeps_the_design_groups_in_the_log(tmp_path: Path, run_log) -> None:
    """The groups the runner copied from the plan's design summary decide the stages of `fit RUN.h5` alone."""
    import h5py

    log, _ = run_log(tmp_path / "run.h5")
    groups = [{"parameters": ["R_s_p"], "selected": ["37"]}, {"parameters": ["R_s_n"], "selected": ["28"]}]
    with h5py.File(log, "a") as f:
        meta = json.loads(f.attrs["meta"])
        f.attrs["meta"] = json.dumps({**meta, "design_groups": groups})
    found = runlog.logged_groups([load_data(log)])
    assert [(g.parameters, set(g.selected)) for g in found] == [(("R_s_p",), {"37"}), (("R_s_n",), {"28"})]


def test_a_profile_selected_by_several_groups_is_fitted_once_per_run(tmp_path: Path, run_log) -> None:
    """The design may select one profile in several groups (the plan then runs it once per group): each run of it
    joins the stage of its own group, none is counted twice."""
    log, _ = run_log(tmp_path / "run.h5", ids=(28, 28))
    data = load_data(log)
    exps = runlog.experiments(data, Cell.load("nca18650"))
    assert [e.name for e in exps] == ["run:28s5", "run:28s9"]
    groups = [(("R_s_n",), {"28"}), (("R_s_p",), {"28"})]
    stages = workflow.stages(None, None, exps, groups)
    assert [[e.name for e in s.experiments] for s in stages] == [["run:28s5"], ["run:28s9"]]


def test_the_groups_of_several_run_logs_are_merged(tmp_path: Path, run_log) -> None:
    """Two run logs of two plans (group 1's profile, then group 2's, as a sequential design runs them): group k
    holds the profiles every log's group k selected, so each log's profile joins its own stage."""
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.io.logs import open_log
    from protocols import Library

    first, _ = run_log(tmp_path / "run.h5", ids=(28,))
    data = load_data(first)
    # the same rows, run from a plan whose profile step is labelled group 2 and runs profile 37's id
    proto = grouped_protocol("second", [(2, [Library.build()[37]])], "test", ocv_table(Cell.load("nca18650")))
    meta = {**data.meta, "plan": {**proto.to_dict(), "run": {}}}
    second = tmp_path / "second.h5"
    with open_log(second, list(data.columns), meta) as w:
        w.append(dict(data.columns))
    logs = [data, load_data(second)]
    groups = runlog.logged_groups(logs)
    assert [set(g.selected) for g in groups[:2]] == [{"28"}, {"37"}]
    exps = [e for d in logs for e in runlog.experiments(d, Cell.load("nca18650"))]
    stages = workflow.stages(None, None, exps, [(g.parameters, set(g.selected)) for g in groups])
    assert [[e.name for e in s.experiments] for s in stages[:2]] == [["run:28"], ["second:37"]]


def test_run_logs_of_the_same_name_keep_apart(tmp_path: Path, run_log) -> None:
    """Two run logs named run.h5 in two directories (a sequential design's): their experiments get distinct
    names, so the summary's RMSE and the stages list both."""
    logs = []
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        logs.append(load_data(run_log(tmp_path / d / "run.h5", ids=(28,))[0]))
    exps = workflow.unique_names([e for d in logs for e in runlog.experiments(d, Cell.load("nca18650"))])
    assert [e.name for e in exps] == ["run:28", "run:28~2"]


def test_a_plans_noise_trials_give_the_fits_noise_model_and_are_not_fitted(tmp_path: Path, run_log) -> None:
    """Three noise trials of profile 28 (labelled 'noise: ...') at the start of the plan: eq. 36 over the trials
    gives the noise level they carry (white, 150 uV), the fit's experiments are the design's profiles alone, weighted
    by the model fitted to the trials, and the summary says so; a noise file given instead wins."""
    from battlab.identify.weights import PAPER, weigh
    from battlab.noise import NoiseModel, save

    log, _ = run_log(tmp_path / "run.h5", ids=(37,), noise=(28,), trials=3, noise_q=150e-6)
    exps = runlog.experiments(load_data(log), Cell.load("nca18650"))
    assert [e.name for e in exps] == ["run:28s5", "run:28s9", "run:28s13", "run:37"]
    assert [bool(e.profile.params.get("noise_trial")) for e in exps] == [True, True, True, False]
    kept, model, info = weigh(exps)
    assert [e.name for e in kept] == ["run:37"]
    assert info["source"].startswith("fitted to repeated trials (1 profiles, 3 trials")
    assert [(t["profile"], t["trials"]) for t in info["trials"]] == [("28", 3)]
    assert info["trials"][0]["q_V"] == pytest.approx(150e-6, rel=0.1)
    assert model.q(kept[0].profile) == pytest.approx(150e-6, rel=0.1)  # a discharge like 28: its measured level
    assert np.all(np.asarray(kept[0].variance) == pytest.approx(model.q(kept[0].profile) ** 2 + 1e-8 / 12, rel=1e-9))
    given = NoiseModel(0.0, 3e-4, 3e-4, 0.0, 1e-5)
    kept, model, info = weigh(exps, save(given, tmp_path / "noise.toml"))
    assert model == given and info["source"] == f"file {tmp_path / 'noise.toml'}" and len(info["trials"]) == 1
    _, model, info = weigh([e for e in exps if not e.profile.params.get("noise_trial")])
    assert model == NoiseModel() and info["source"] == PAPER and info["trials"] == []


@pytest.mark.slow
def test_a_profile_after_a_full_charge_starts_from_it_with_the_preparation_as_lead_in(tmp_path: Path) -> None:
    """A one-profile plan (full charge, rest, C/2 discharge to SOC 0.8, 30 min rest, a 600 s pulse train) run on the
    in-process virtual tester (the hidden truth nca18650-true): the experiment replays the preparation from the end
    of the full charge, unscored, and the true cell on its own log comes near the tester's noise, where the uniform
    start at the rest's SOC left the negative electrode's slow relaxation (tau 4.3 h) in the residual."""
    import dataclasses

    import tomli_w

    import battlab
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.identify.forward import ForwardModel
    from battlab.lab.session import RunSettings, start_run
    from drivers.virtual.noise import NoiseModel
    from protocols import Library

    lib = Library.build()
    proto = grouped_protocol("lead-in", [(1, [lib[28]])], "test", ocv_table(Cell.load("nca18650")))
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps({**proto.to_dict(), "run": {"stable_hold_s": 0.0}}))
    log = tmp_path / "run.h5"
    settings = RunSettings("virtual", "virtual", cell="nca18650-true", speed=1000, seed=3)
    assert start_run(plan, settings, log, display=False).status == "completed"
    truth = battlab.Cell.load("nca18650-true")
    (e,) = runlog.experiments(load_data(log), truth)
    assert e.lead_in > 0 and 0.95 < e.soc0 < 1.0  # from the full charge's end
    assert e.mask.sum() == e.scored_voltage.size == 601 and e.hours == pytest.approx(600 / 3600, abs=1e-3)
    fm = ForwardModel(truth, v_margin=0.15)

    def rmse(x) -> float:
        out = fm.run(truth.theta_bar(), x.profile, x.soc0, ambient=x.ambient, T0=x.T0)
        assert out.voltage.size == x.voltage.size
        return float(np.sqrt(np.mean((out.voltage - x.voltage)[x.mask] ** 2)))

    m = NoiseModel()
    sigma = m.voltage_white_V + m.voltage_per_amp_V * np.abs(e.scored_profile.current)
    noise = float(np.sqrt(np.mean(sigma**2) + m.voltage_quantum_V**2 / 12))
    soc_rest = e.soc0 + float(np.sum(e.profile.current[: e.lead_in] * np.diff(e.profile.t[: e.lead_in + 1]))) / (
        3600 * truth.capacity()
    )
    uniform = dataclasses.replace(
        e,
        profile=e.scored_profile,
        voltage=e.scored_voltage,
        soc0=soc_rest,
        mask=None,
        lead_in=0,
        variance=1e-8,
        temperature=None if e.temperature is None else e.temperature[e.lead_in :],
    )
    with_lead_in, from_uniform = rmse(e), rmse(uniform)
    print(f"truth on its log: {1e3 * with_lead_in:.3f} mV with the lead-in, {1e3 * from_uniform:.3f} mV uniform")
    # measured (seed 3): 0.374 mV with the lead-in, 1.06 mV from the uniform start; the tester's noise 0.210 mV
    assert with_lead_in < 2.0 * noise < 3.5 * noise < from_uniform


@pytest.mark.slow
def test_the_model_changes_the_current_when_the_tester_did_not_at_the_samples_time_stamp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The virtual tester sets each current, then measures: its log's samples are read 10 ms after the change
    (the run's statistics say so). With its noise off, the true cell on its own log is within the scheme's accuracy
    when the experiment's model changes the current that much before each sample, and misses by the relaxation in
    those 10 ms when it changes it at the time stamp."""
    import tomli_w

    import battlab
    from battlab.design.plan import grouped_protocol, ocv_table
    from battlab.identify.forward import ForwardModel
    from battlab.lab.session import RunSettings, start_run
    from drivers.virtual.noise import NoiseModel
    from protocols import Library

    monkeypatch.setattr(NoiseModel, "voltage", lambda self, v, *args, **kwargs: v)
    monkeypatch.setattr(NoiseModel, "current", lambda self, i, rng: i)
    monkeypatch.setattr(NoiseModel, "temperature", lambda self, T, rng: T)
    lib = Library.build()
    proto = grouped_protocol("delay", [(1, [lib[541]])], "test", ocv_table(Cell.load("nca18650")))
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps({**proto.to_dict(), "run": {"stable_hold_s": 0.0}}))
    log = tmp_path / "run.h5"
    assert start_run(plan, RunSettings("virtual", "virtual", cell="nca18650-true"), log, display=False).status == (
        "completed"
    )
    data = load_data(log)
    truth = battlab.Cell.load("nca18650-true")
    (e,) = runlog.experiments(data, truth)
    stats = data.meta["final"]["stats"]
    assert e.sample_delay == pytest.approx(stats["mean_set_to_sample_s"]) and 0.005 < e.sample_delay < 0.03
    fm = ForwardModel(truth, v_margin=0.15)

    def rmse_mV(delay: float) -> float:
        """Best over the start SOC (the preparation's CV end leaves it known to about 1e-4)."""
        best = np.inf
        for ds in np.linspace(-5e-4, 5e-4, 21):
            out = fm.run(truth.theta_bar(), e.profile, e.soc0 + ds, ambient=e.ambient, T0=e.T0, sample_delay=delay)
            best = min(best, float(np.sqrt(np.mean((out.voltage - e.voltage)[e.mask] ** 2))))
        return 1e3 * best

    led, at_stamp = rmse_mV(e.sample_delay), rmse_mV(0.0)
    print(f"noiseless log: {led:.4f} mV with the {1e3 * e.sample_delay:.1f} ms lead, {at_stamp:.4f} without")
    # measured: 0.021 mV with the lead, 0.069 mV without (the tester's noise is 0.19 mV)
    assert led < 0.03 and 3 * led < at_stamp
