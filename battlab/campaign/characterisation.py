"""The campaign's characterisation stages on the tester: the capacity check (before and after), the OCV test and
the equilibrium fit from it, and the repeated trials that fit the noise model (eq. 36-39)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign.context import Campaign, health_file, plain, rel_path, write_json
from battlab.campaign.stages import StageContext, StageOutput
from battlab.cell import Cell
from battlab.design.noise_trials import noise_profiles

#: simulations of the slow cycle in the equilibrium fit of the quick campaign (each new ε_s compiles a model)
QUICK_SIMULATIONS = 4


def capacity(camp: Campaign, which: str) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        n0 = len(camp.runs)
        out = camp.run(P.capacity_check(camp.q_rated, camp.ambient), f"capacity_{which}")
        ah = D.discharged_ah(out.log_path, P.CAPACITY_STEP)
        rel_log = str(out.log_path.relative_to(ctx.directory))
        health = health_file(camp, ctx, f"capacity_{which}", n0)
        summary = {"capacity_Ah": ah, "rated_Ah": camp.q_rated, "c_rate": "C/3 after CCCV", "hours": out.hours}
        return StageOutput({"log": rel_log, "health": health}, summary, out.hours)

    return run


def ocv(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        n0 = len(camp.runs)
        out = camp.run(P.ocv_test(camp.q_rated, camp.ambient), "ocv")
        rel = str(out.log_path.relative_to(ctx.directory))
        health = health_file(camp, ctx, "ocv", n0)
        return StageOutput({"log": rel, "health": health}, {"hours": out.hours, "c_rate": "C/20, one cycle"}, out.hours)

    return run


def ocv_cycle(d: Any) -> Any:
    """The OCV test's slow cycle (:class:`battlab.identify.ocv_model.SlowCycle`) from its loaded log."""
    from battlab.identify.ocv_model import slow_cycle

    m = D.steps(d, P.OCV_FIRST_STEP)
    return slow_cycle(d.t, d.current, d.voltage, int(np.flatnonzero(m)[0]), "ocv")


def equilibrium(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.figures import ocv_fit
        from battlab.identify.ocv_model import MAX_SIMULATIONS, against_truth, fit_equilibrium_model

        d = D.load(ctx.path("ocv", "log"))
        m = D.steps(d, P.OCV_FIRST_STEP)
        cycle = ocv_cycle(d)
        n_sim = QUICK_SIMULATIONS if camp.config.quick else MAX_SIMULATIONS
        eq = fit_equilibrium_model(
            cycle,
            camp.start,
            max_simulations=n_sim,
            progress=lambda k, r, s: ctx.progress(k, n_sim, f"simulation {k}: {r:.3f} mV"),
        )
        out = ctx.directory / "equilibrium"
        out.mkdir(parents=True, exist_ok=True)
        rep = plain(eq.report())
        eq.cell.renamed("equilibrium").to_bpx(out / "equilibrium.bpx.json", equilibrium=rep)
        # the equilibrium cell with the slow cycle's diffusivities: what the designed profiles are screened on
        eq.cell.with_values(**eq.nuisances).renamed("equilibrium-screen").to_bpx(out / "screen.bpx.json")
        if camp.tester.virtual:
            rep["truth"] = plain(against_truth(eq, Cell.load(camp.tester.truth)))
        write_json(out / "summary.json", rep)
        fig = ocv_fit(d.t[m], d.current[m], d.voltage[m], eq.cell, out / "ocv_fit.png")
        files = {
            "cell": "equilibrium/equilibrium.bpx.json",
            "screen_cell": "equilibrium/screen.bpx.json",
            "summary": "equilibrium/summary.json",
            "figure": str(fig.relative_to(ctx.directory)),
        }
        return StageOutput(files, rep)

    return run


def noise(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.figures import noise_model
        from battlab.noise import NoiseModel, direction, intensity, repeat_noise
        from protocols.library import Library

        n0 = len(camp.runs)
        lib = Library.load(ctx.path("library", "library"))
        cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]  # SOC is defined on the equilibrium capacity
        picks = noise_profiles(
            lib,
            camp.config.noise.profiles_per_direction,
            Cell.load(str(ctx.path("equilibrium", "cell"))),
            camp.config.noise.max_duration_s,
        )
        runs_, rows, hours, failed = [], [], 0.0, {}
        reps = camp.config.noise.repeats
        for n, prof in enumerate(picks):
            prep = P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient)
            hours += camp.run(prep, f"noise/{prof.id}_prep").hours
            logs = []
            for trial in range(1, reps + 1):
                ctx.progress(n * reps + trial - 1, len(picks) * reps, f"profile {prof.id} trial {trial}")
                plan = P.measurement(prof, camp.q_rated, camp.ambient, rest_after_s=0.0)
                out = camp.run(plan, f"noise/{prof.id}_trial{trial}", must_complete=False)
                hours += out.hours
                if out.status != "completed":  # the profile is left out of the regression; the others go on
                    failed[str(prof.id)] = out.reason or out.status
                    break
                logs.append(out.log_path)
                dq = D.net_ah(out.log_path)
                if trial < reps and abs(dq) > 1e-3:
                    hours += camp.run(_restore(dq, camp), f"noise/{prof.id}_restore{trial}").hours
            if str(prof.id) in failed:
                continue
            v = D.trial_voltages(logs)
            runs_.append((prof, v))
            q = repeat_noise(v)
            rows.append({"id": prof.id, "direction": direction(prof).value, "intensity": intensity(prof), "q_V": q})
        model = NoiseModel.fit(runs_)
        out = ctx.directory / "noise"
        summary = {"model": model.__dict__, "runs": rows, "failed": failed, "repeats": reps, "hours": hours}
        write_json(out / "noise.json", summary)
        fig = noise_model(rows, model, out / "noise_model.png")
        files = {
            "model": "noise/noise.json",
            "figure": rel_path(ctx, fig),
            "health": health_file(camp, ctx, "noise", n0),
        }
        return StageOutput(files, summary, hours)

    return run


def _restore(dq: float, camp: Campaign) -> Any:
    """Put back the net charge ``dq`` [Ah] a trial passed (C/2), then rest."""
    from protocols.protocol import ConstantCurrent, Rest, after, capacity_reached, voltage_above, voltage_below

    i = -np.sign(dq) * 0.5 * camp.q_rated
    limit = voltage_above(P.V_MAX) if i > 0 else voltage_below(P.V_MIN)
    steps = [
        ConstantCurrent(float(i), (capacity_reached(abs(dq)), limit), "restore the start SOC"),
        Rest((after(1800.0),), "rest"),
    ]
    return P._plan("restore", steps, camp.q_rated, P.COARSE_S, camp.ambient)
