"""The campaign's design stages: the input library, the sensitivity sweep on the equilibrium cell, the parameter
groups, the optimal designs per group, and the designed experiments run on the tester."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign.context import Campaign, RunFailed, health_file, read_json, rel_path, write_json
from battlab.campaign.stages import StageContext, StageOutput
from battlab.cell import Cell
from protocols.errors import InputError


def library(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from protocols.library import Library

        lib = Library.build()
        lib.save(ctx.directory / "library.h5")
        ids = list(camp.config.library.ids) or list(lib.ids)
        unknown = [i for i in ids if i not in lib]
        if unknown:
            raise InputError(f"library.ids: no profile {unknown[0]} in the library (ids 1..{len(lib)})")
        summary = {"profiles": len(lib), "selected": len(ids), "ids": ids, "hours": lib.total_hours}
        return StageOutput({"library": "library.h5"}, summary)

    return run


def sweep(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.design.workflow import sweep as do_sweep
        from battlab.design.workflow import sweep_summary
        from battlab.progress import ProgressEvent

        def sub(ev: ProgressEvent) -> None:
            if ev.kind == "advance":
                ctx.progress(ev.done, ev.total, ev.text)

        # the designs' sensitivities and window screen on what the OCV test showed: the equilibrium cell with the slow
        # cycle's diffusivities where the equilibrium stage fitted them (on the virtual lab it predicts the truth's
        # voltage under the pulses that abort within 5 mV; the start dynamics miss it by 0.5 V)
        eq_files = ctx.inputs["equilibrium"].files
        cell = Cell.load(str(ctx.path("equilibrium", "screen_cell" if "screen_cell" in eq_files else "cell")))
        ids = ctx.inputs["library"].summary["ids"]
        store = ctx.directory / "sensitivity.h5"
        store.unlink(missing_ok=True)
        rep = do_sweep(
            ctx.path("library", "library"),
            cell,
            store,
            ids=ids,
            ambient_C=camp.ambient,
            conventional=not camp.config.quick,
            workers=1 if len(ids) <= 50 else None,  # the whole library on every core; a subset in-process
            subscribers=[sub],
        )
        summary = sweep_summary(rep)
        if summary["ok"] == 0:
            raise InputError(f"sensitivity sweep: no profile simulated ({summary['failures']})")
        return StageOutput({"store": "sensitivity.h5"}, summary)

    return run


def groups(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.design.workflow import groups as do_groups

        out = ctx.directory / "groups"
        rep = do_groups(ctx.path("sweep", "store"), out_dir=out, perturb=False)
        groups_ = rep.groups if camp.config.design.groups == "computed" else [list(g) for g in _table9()]
        data = {"groups": groups_, "computed": rep.groups, "source": camp.config.design.groups}
        data["ranking"] = rep.data["ranking"]
        write_json(out / "campaign_groups.json", data)
        files = {"groups": "groups/campaign_groups.json", "ranking_figure": rel_path(ctx, rep.figures[0])}
        return StageOutput(files, {"groups": groups_, "source": camp.config.design.groups})

    return run


def _table9() -> Sequence[Sequence[str]]:
    from battlab.parameters import TABLE9_GROUPS

    return TABLE9_GROUPS


def design(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.design.workflow import design as design_plan
        from battlab.noise import NoiseModel

        grp = read_json(ctx.path("groups", "groups"))["groups"]
        model = NoiseModel(**read_json(ctx.path("noise", "model"))["model"])
        out = ctx.directory / "plan" / "plan.toml"
        c = camp.config.design
        rep = design_plan(
            ctx.path("sweep", "store"), out, criterion=c.criterion, M=c.profiles_per_group, noise=model, groups=grp
        )
        summary = json.loads(Path(rep.files.summary).read_text())
        selected = [pid for d in rep.designs for pid in d.selected]
        out_summary = {
            "criterion": summary["criterion"],
            "groups": [
                {"parameters": g["parameters"], "selected": g["selected"], "logdet": g.get("logdet")}
                for g in summary["groups"]
            ],
            "solve_seconds": rep.solve_seconds,
            "n_candidates": rep.n_candidates,
            "selected_profiles": {str(pid): _profile_meta(rep.meta[pid]) for pid in selected},
            "replacements": summary.get("replacements", {}),
            "voltage_span": summary.get("voltage_span", {}),
        }
        figure = str(Path(rep.figure).resolve().relative_to(ctx.directory.resolve()))
        files = {"plan": "plan/plan.toml", "summary": "plan/plan.summary.json", "figure": figure}
        return StageOutput(files, out_summary)

    return run


def _profile_meta(m: Mapping[str, Any]) -> dict[str, Any]:
    return {k: m[k] for k in ("kind", "soc0", "duration") if k in m} | {"params": m.get("params")}


def experiments(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.design.replacement import SCREEN_MARGIN_V, Guard, run_designed, simulated_span
        from protocols.library import Library
        from protocols.steps import SafetyLimits

        n0 = len(camp.runs)
        lib = Library.load(ctx.path("library", "library"))
        cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]  # SOC is defined on the equilibrium capacity
        design = ctx.inputs["design"].summary
        ids = selected_ids(design)
        spares = {int(k): [int(c) for c in v] for k, v in design.get("replacements", {}).items()}
        spans = {int(k): (float(v[0]), float(v[1])) for k, v in design.get("voltage_span", {}).items()}
        hours, logs, preps, failed = [0.0], {}, {}, {}

        def one(pid: int) -> tuple[bool, str, float]:
            # a profile the cell cannot follow (a safety limit, a model failure of the virtual cell) is recorded,
            # replaced by its best spare (battlab.design.replacement) and left out of the fit; the others go on
            ctx.progress(len(logs), len(ids), f"profile {pid}")
            prof = lib[pid]
            prep = camp.run(P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient), f"oed/{pid}_prep")
            out = camp.run(camp.measurement(prof), f"oed/{pid}", must_complete=False)
            hours[0] += prep.hours + out.hours
            if out.status == "completed":
                logs[str(pid)] = rel_path(ctx, out.log_path)
                preps[str(pid)] = rel_path(ctx, prep.log_path)  # the fit's lead-in into the measurement
                return True, "completed", float("nan")
            failed[str(pid)] = out.reason or out.status
            d = D.load(out.log_path)
            return False, failed[str(pid)], float(d.voltage[-1]) if len(d) else float("nan")

        lim = SafetyLimits()  # the measurement plans' abort limits
        guard = Guard(lim.voltage_min, lim.voltage_max)
        screen = None
        if "screen_cell" in ctx.inputs["equilibrium"].files:  # profiles screened again on what the OCV test showed
            screen = Cell.load(str(ctx.path("equilibrium", "screen_cell")))
            guard = Guard(lim.voltage_min, lim.voltage_max, SCREEN_MARGIN_V, SCREEN_MARGIN_V)
            spans = {}

        def span(pid: int) -> tuple[float, float]:
            if pid not in spans and screen is not None:
                limits = (lim.voltage_min, lim.voltage_max)
                spans[pid] = simulated_span(screen, lib[pid], camp.ambient + 273.15, limits)
            return spans.get(pid, (-np.inf, np.inf))

        attempts = run_designed(ids, spares, span, one, guard)
        if not logs:
            raise RunFailed(f"no designed experiment completed ({'; '.join(f'{k}: {v}' for k, v in failed.items())})")
        files = {f"log_{k}": v for k, v in logs.items()} | {f"prep_{k}": v for k, v in preps.items()}
        files["health"] = health_file(camp, ctx, "experiments", n0)
        summary = {
            "profiles": ids,
            "completed": [int(k) for k in logs],
            "failed": failed,
            "replaced": {str(a.designed): a.used for a in attempts if a.used not in (None, a.designed)},
            "lost": [a.designed for a in attempts if a.used is None],
            "attempts": {str(a.designed): {str(k): v for k, v in a.tried.items()} for a in attempts},
            "voltage_span": {str(k): [x if np.isfinite(x) else None for x in v] for k, v in spans.items()},
            "screened_on": "equilibrium cell with the slow cycle's diffusivities" if screen else "design cell",
            "hours": hours[0],
        }
        return StageOutput(files, summary, hours[0])

    return run


def selected_ids(design_summary: dict[str, Any]) -> list[int]:
    """The distinct profiles a design selected, in group order."""
    out: list[int] = []
    for g in design_summary["groups"]:
        out += [int(p) for p in g["selected"] if int(p) not in out]
    return out
