"""The campaign's assessment stages: the cumulative fits of the designed experiments, the conventional baseline
(its tests on the tester, fitted the same way), validation on held-out tests (nominal vs conventional vs OED), the
BPX export."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign.context import Campaign, health_file, read_json, rel_path
from battlab.campaign.stages import StageContext, StageOutput
from battlab.cell import Cell
from protocols.errors import InputError

#: validation: constant-current discharges from full (Table 12; the quick campaign: 1C only) and a held-out drive
#: cycle (US06 from SOC 0.8)
VALIDATION_CC = (0.5, 1.0)
VALIDATION_CC_QUICK = (1.0,)
VALIDATION_DRIVE_ID = 722
#: conventional tests (C-rates; negative = discharge from full, positive = charge from empty) plus UDDS from 0.8
CONVENTIONAL_FULL = (-0.1, -0.2, -1 / 3, -2.0, 0.2, 0.5, 1.0)
CONVENTIONAL_QUICK = (-1 / 3, -2.0)
#: the conventional fit's sampling of constant-current data [s]
CC_DT = 10.0


def fit_oed(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        """``battlab fit`` on the designed experiments' run logs, stages from the design's groups."""
        from battlab.campaign.identify import finish, settings
        from battlab.identify.fit_options import FitOptions
        from battlab.identify.workflow import fit
        from battlab.progress import ProgressEvent

        cell_path = ctx.path("equilibrium", "cell")
        logs, preps = experiment_logs(ctx)
        replaced = ctx.inputs["experiments"].summary.get("replaced", {})  # a spare's data fill its profile's place
        groups = tuple(
            (tuple(g["parameters"]), frozenset(str(replaced.get(str(p), p)) for p in g["selected"]))
            for g in ctx.inputs["design"].summary["groups"]
        )
        s = settings(camp)
        options = FitOptions(
            data=tuple(logs),
            cell=cell_path,
            groups=groups,
            noise=ctx.path("noise", "model"),
            max_iter=s.max_evaluations,
            polish=s.polish,
            preparations=preps,
            output=ctx.directory / "fit" / "oed.bpx.json",
        )

        def show(ev: ProgressEvent) -> None:
            if ev.kind == "note" and ev.payload is not None and hasattr(ev.payload, "stage"):
                st = ev.payload
                ctx.progress(st.stage, st.total, f"stage {st.stage} of {st.total} done")

        rep = fit(options, [show])
        summary = dict(rep.summary)
        summary["data_hours"] = float(sum(e.hours for e in rep.experiments))
        finish(summary, camp, Cell.load(str(cell_path)))
        rep.summary = summary
        rep.write(options.output)
        return StageOutput({"cell": "fit/oed.bpx.json", "summary": "fit/oed.summary.json"}, summary)

    return run


def experiment_logs(ctx: StageContext) -> tuple[list[Path], tuple[tuple[Path, Path], ...]]:
    """The designed experiments' logs and (log, its preparation's log) pairs, for the fit's lead-ins."""
    files = ctx.inputs["experiments"].files
    logs = {k.removeprefix("log_"): ctx.directory / v for k, v in files.items() if k.startswith("log_")}
    preps = tuple((p, ctx.directory / files[f"prep_{k}"]) for k, p in logs.items() if f"prep_{k}" in files)
    return list(logs.values()), preps


def conventional(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.identify import cumulative_fit
        from battlab.identify.fit import Stage as FitStage
        from battlab.noise import NoiseModel
        from battlab.parameters import NAMES
        from protocols.drive_cycles import Cycle, drive_profile

        n0 = len(camp.runs)
        cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]  # SOC is defined on the equilibrium capacity
        cell = Cell.load(str(ctx.path("equilibrium", "cell")))
        model = NoiseModel(**read_json(ctx.path("noise", "model"))["model"])
        rates = camp.config.conventional.c_rates or (CONVENTIONAL_QUICK if camp.config.quick else CONVENTIONAL_FULL)
        hours, exps, files, notes = 0.0, [], {}, {}
        for k, c in enumerate(rates):
            ctx.progress(k, len(rates) + 1, f"{abs(c):.3g}C {'charge' if c > 0 else 'discharge'}")
            prep = (
                P.prepare_empty(camp.q_rated, camp.ambient)
                if c > 0
                else P.prepare(1.0, camp.q_rated, cap, camp.ambient)
            )
            prepared = camp.run(prep, f"conventional/cc_{c:+.3g}C_prep")
            out = camp.run_to_limit(
                P.constant_current(c, camp.q_rated, camp.ambient, rest_after_s=camp.rest_after_s),
                f"conventional/cc_{c:+.3g}C",
                notes,
            )
            hours += prepared.hours + out.hours
            files[f"log_cc_{c:+.3g}C"] = rel_path(ctx, out.log_path)
            name = f"CC {c:+.3g}C"
            exps.append(
                D.experiment(out.log_path, cell, name=name, noise=model, dt=CC_DT)
                if c > 0  # from empty: no full charge to start a lead-in from
                else D.experiment_after_preparation(
                    prepared.log_path, out.log_path, cell, name=name, noise=model, dt=CC_DT
                )
            )
        ctx.progress(len(rates), len(rates) + 1, "UDDS")
        udds = drive_profile(Cycle.UDDS, soc0=0.8, id="UDDS")
        prepared = camp.run(P.prepare(0.8, camp.q_rated, cap, camp.ambient), "conventional/udds_prep")
        out = camp.run(camp.measurement(udds), "conventional/udds")
        hours += prepared.hours + out.hours
        files["log_udds"] = rel_path(ctx, out.log_path)
        exps.append(D.experiment_after_preparation(prepared.log_path, out.log_path, cell, name="UDDS", noise=model))
        fit_dir = ctx.directory / "conventional"
        summary = cumulative_fit(
            cell, [FitStage(tuple(NAMES), tuple(exps))], camp, fit_dir / "conventional.bpx.json", ctx.progress
        )
        summary["test_hours"] = hours
        summary["notes"] = notes
        files.update(cell="conventional/conventional.bpx.json", health=health_file(camp, ctx, "conventional", n0))
        return StageOutput(files, summary, hours)

    return run


def validation(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.identify import score
        from protocols.library import Library

        n0 = len(camp.runs)
        cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]  # SOC is defined on the equilibrium capacity
        lib = Library.load(ctx.path("library", "library"))
        hours, logs, notes = 0.0, {}, {}
        for c in camp.config.validation.c_rates or (VALIDATION_CC_QUICK if camp.config.quick else VALIDATION_CC):
            if c <= 0:
                raise InputError(f"validation.c_rates: {c}: give discharge rates as positive C-rates")
            hours += camp.run(P.prepare(1.0, camp.q_rated, cap, camp.ambient), f"validation/cc_{c:g}C_prep").hours
            out = camp.run_to_limit(
                P.constant_current(-c, camp.q_rated, camp.ambient, rest_after_s=camp.rest_after_s),
                f"validation/cc_{c:g}C",
                notes,
            )
            hours += out.hours
            logs[f"{c:g}C discharge"] = (out.log_path, CC_DT)
        prof = lib[VALIDATION_DRIVE_ID]
        prepared = camp.run(P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient), "validation/drive_prep")
        out = camp.run(camp.measurement(prof), "validation/drive")
        hours += prepared.hours + out.hours
        drive = f"{prof.params.get('name', 'drive')} from SOC {prof.soc0:g}"
        logs[drive] = (out.log_path, 1.0)
        cells = {
            "nominal": Cell.load(str(ctx.path("equilibrium", "cell"))),
            "conventional": Cell.load(str(ctx.path("conventional", "cell"))),
            "OED": Cell.load(str(ctx.path("fit", "cell"))),
        }
        truth = Cell.load(camp.tester.truth) if camp.tester.virtual else None
        summary = score(logs, cells, truth, ctx.directory / "validation")
        summary["hours"] = hours
        summary["notes"] = notes
        files = {f"log_{k}": rel_path(ctx, p) for k, (p, _) in logs.items()}
        files[f"prep_{drive}"] = rel_path(ctx, prepared.log_path)  # the diagnosis's held-out lead-in
        files.update(summary="validation/validation.json", health=health_file(camp, ctx, "validation", n0))
        return StageOutput(files, summary, hours)

    return run


def export(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        cell = Cell.load(str(ctx.path("fit", "cell")))
        cell.renamed("campaign").to_bpx(ctx.directory / "cell.bpx.json")  # validated by the bpx package as written
        back = Cell.load(str(ctx.directory / "cell.bpx.json"))
        from battlab.parameters import NAMES

        names = (*NAMES, "eps_s_n", "eps_s_p", "n_Li")
        worst = max(abs(float(back[n]) / float(cell[n]) - 1) for n in names if _number(cell[n]))
        summary = {"bpx": "cell.bpx.json", "check": "bpx-validated; reloads", "max_relative_change": worst}
        return StageOutput({"bpx": "cell.bpx.json"}, summary)

    return run


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and x != 0
