"""The campaign's stages, in order, as functions registered with the stage runner (:mod:`battlab.campaign.stages`).

capacity check → OCV test → equilibrium fit → library → sensitivity sweep → groups → repeated trials and the
noise model → designs per group → the designed experiments on the tester → cumulative fits with intervals →
conventional baseline (its tests on the tester, fitted the same way) → validation (held-out tests on the tester;
nominal vs conventional vs OED) → diagnosis (residual analysis) → capacity check again → BPX export → report.

Each stage writes its artefacts under the campaign directory and returns its files, a JSON summary and the lab
hours it used. Runs on the tester are logged under ``runs/``; a run that does not complete fails its stage.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign.config import CampaignConfig
from battlab.campaign.stages import Stage, StageContext, StageOutput
from battlab.campaign.tester import RunOutcome, Tester, VirtualBench, run_plan
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
#: how far [V] a noise profile simulated on the start cell must stay above V_min and below V_max (the truth may be
#: more polarised than the start: 0.3-0.5 V more at the end of long discharges, tens of mV on charge)
NOISE_MARGIN_V = (0.2, 0.1)
#: the largest current [C] of a noise profile
NOISE_MAX_C = 3.0
#: the conventional fit's sampling of constant-current data [s]
CC_DT = 10.0


class RunFailed(Exception):
    """A run on the tester did not complete."""


def _json(path: Path, data: Any) -> None:
    from battlab.identify.workflow import json_default

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, default=json_default))


def _read(path: Path) -> Any:
    return json.loads(path.read_text())


@dataclass
class Campaign:
    """What every stage shares: settings, where plans run, the virtual bench, the campaign directory."""

    config: CampaignConfig
    tester: Tester
    directory: Path
    bench: VirtualBench | None = None
    runs: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.tester.virtual and self.bench is None:
            self.bench = VirtualBench(self.tester, self.config.campaign.ambient_degC)

    @property
    def ambient(self) -> float:
        return self.config.campaign.ambient_degC

    @property
    def start(self) -> Cell:
        return Cell.load(self.config.campaign.start)

    @property
    def rest_after_s(self) -> float:
        """The rest logged after each measured profile [s]: 600 s, 300 s in the quick campaign."""
        return 300.0 if self.config.quick else P.REST_AFTER_S

    def measurement(self, prof: Any) -> Any:
        return P.measurement(prof, self.q_rated, self.ambient, rest_after_s=self.rest_after_s)

    @property
    def q_rated(self) -> float:
        return float(self.start["Q_nom"])

    def run(self, plan: Any, rel: str, *, must_complete: bool = True) -> RunOutcome:
        """Run ``plan`` to ``runs/<rel>.h5`` (a log left by an interrupted attempt is moved aside first); a run that
        does not complete raises :class:`RunFailed` unless ``must_complete`` is False."""
        path = self.directory / "runs" / f"{rel}.h5"
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            k = 1
            while path.with_name(f"{path.stem}.interrupted-{k}.h5").exists():
                k += 1
            path.rename(path.with_name(f"{path.stem}.interrupted-{k}.h5"))
        w0 = time.perf_counter()
        out = run_plan(plan, self.tester, path, cell=self.config.campaign.start, bench=self.bench)
        self.runs.append({**out.health(), "wall_s": time.perf_counter() - w0})
        if out.status != "completed" and must_complete:
            raise RunFailed(f"run {rel} {out.status}: {out.reason}")
        return out

    def run_to_limit(self, plan: Any, rel: str, notes: dict[str, str], step: int = 2) -> RunOutcome:
        """A constant-current test to a voltage limit: one that aborted in or after its test step (at the cut-off
        the virtual cell's model may fail to converge, also in the current step to the rest after it) keeps its data
        up to there, noted in ``notes``; any other failure raises :class:`RunFailed`."""
        out = self.run(plan, rel, must_complete=False)
        if out.status == "completed":
            return out
        if out.status == "aborted" and _ended_in_step(out, step):
            notes[rel] = f"ended early in or after the test step: {out.reason}"
            return out
        raise RunFailed(f"run {rel} {out.status}: {out.reason}")


def _ended_in_step(out: RunOutcome, step: int) -> bool:
    d = D.load(out.log_path)
    return len(d) >= 10 and int(d.columns[D.STEP_INDEX][-1]) >= step


def _health_file(camp: Campaign, ctx: StageContext, name: str, first: int) -> str:
    rel = f"health/{name}.json"
    _json(ctx.directory / rel, camp.runs[first:])
    return rel


# -- stages ------------------------------------------------------------------------------------------------
def capacity(camp: Campaign, which: str) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        n0 = len(camp.runs)
        out = camp.run(P.capacity_check(camp.q_rated, camp.ambient), f"capacity_{which}")
        ah = D.discharged_ah(out.log_path, P.CAPACITY_STEP)
        rel_log = str(out.log_path.relative_to(ctx.directory))
        health = _health_file(camp, ctx, f"capacity_{which}", n0)
        summary = {"capacity_Ah": ah, "rated_Ah": camp.q_rated, "c_rate": "C/3 after CCCV", "hours": out.hours}
        return StageOutput({"log": rel_log, "health": health}, summary, out.hours)

    return run


def ocv(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        n0 = len(camp.runs)
        out = camp.run(P.ocv_test(camp.q_rated, camp.ambient), "ocv")
        rel = str(out.log_path.relative_to(ctx.directory))
        health = _health_file(camp, ctx, "ocv", n0)
        return StageOutput({"log": rel, "health": health}, {"hours": out.hours, "c_rate": "C/20, one cycle"}, out.hours)

    return run


def equilibrium(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.figures import ocv_fit
        from battlab.identify.equilibrium import fit_equilibrium, ocv_curve

        d = D.load(ctx.path("ocv", "log"))
        m = D.steps(d, P.OCV_FIRST_STEP)
        eq = fit_equilibrium(ocv_curve(d.t[m], d.current[m], d.voltage[m], source="ocv"), camp.start)
        out = ctx.directory / "equilibrium"
        out.mkdir(parents=True, exist_ok=True)
        eq.cell.renamed("equilibrium").to_bpx(out / "equilibrium.bpx.json", equilibrium=_plain(eq.report()))
        rep = _plain(eq.report())
        if camp.tester.virtual:
            truth = Cell.load(camp.tester.truth)
            rep["truth"] = {k: float(truth[k]) for k in ("eps_s_n", "eps_s_p", "n_Li")}
            rep["truth"]["capacity_Ah"] = float(truth.capacity())
        _json(out / "summary.json", rep)
        fig = ocv_fit(d.t[m], d.current[m], d.voltage[m], eq.cell, out / "ocv_fit.png")
        files = {"cell": "equilibrium/equilibrium.bpx.json", "summary": "equilibrium/summary.json"}
        files["figure"] = str(fig.relative_to(ctx.directory))
        return StageOutput(files, rep)

    return run


def _plain(rep: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(rep, default=lambda o: o.item() if hasattr(o, "item") else str(o)))


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
        from battlab.design.workflow import sweep_summary
        from battlab.progress import ProgressEvent
        from battlab.workflow import sweep as do_sweep

        def sub(ev: ProgressEvent) -> None:
            if ev.kind == "advance":
                ctx.progress(ev.done, ev.total, ev.text)

        cell = Cell.load(str(ctx.path("equilibrium", "cell")))
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
        from battlab.workflow import groups as do_groups

        out = ctx.directory / "groups"
        rep = do_groups(ctx.path("sweep", "store"), out_dir=out, perturb=False)
        groups_ = rep.groups if camp.config.design.groups == "computed" else [list(g) for g in _table9()]
        data = {"groups": groups_, "computed": rep.groups, "source": camp.config.design.groups}
        data["ranking"] = rep.data["ranking"]
        _json(out / "campaign_groups.json", data)
        files = {"groups": "groups/campaign_groups.json", "ranking_figure": _rel(ctx, rep.figures[0])}
        return StageOutput(files, {"groups": groups_, "source": camp.config.design.groups})

    return run


def _table9() -> Sequence[Sequence[str]]:
    from battlab.parameters import TABLE9_GROUPS

    return TABLE9_GROUPS


def _rel(ctx: StageContext, p: str | Path) -> str:
    return str(Path(p).resolve().relative_to(ctx.directory.resolve()))


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
        _json(out / "noise.json", summary)
        fig = noise_model(rows, model, out / "noise_model.png")
        files = {"model": "noise/noise.json", "figure": _rel(ctx, fig), "health": _health_file(camp, ctx, "noise", n0)}
        return StageOutput(files, summary, hours)

    return run


def noise_profiles(lib: Any, per_direction: int, cell: Cell | None = None, max_s: float = 3600.0) -> list[Any]:
    """Pulse profiles that only charge and that only discharge, ``per_direction`` of each, spread over the range of
    intensities (eq. 38 fits one line per direction), from the library's outer start SOCs (discharges from 0.8,
    charges from 0.2: their 1 Ah, 37 % of SOC, stays away from the ends, where the truth may be far more polarised
    than the start cell). With ``cell``: at most :data:`NOISE_MAX_C`, and a profile whose simulation on ``cell``
    comes within :data:`NOISE_MARGIN_V` of a voltage limit is passed over for the next gentler one (a repeated
    trial must not end at a safety limit). Profiles longer than ``max_s`` [s] are left out."""
    from battlab.noise import direction, intensity

    out = []
    cell_c = float(cell["Q_nom"]) if cell is not None else 0.0
    for d in ("discharge", "charge"):
        fits = (lambda p: p.soc0 >= 0.8) if d == "discharge" else (lambda p: p.soc0 <= 0.2)
        gentle = (
            (lambda p: float(np.abs(p.current).max()) <= NOISE_MAX_C * cell_c) if cell is not None else (lambda p: True)
        )
        cands = [
            p
            for p in lib
            if p.kind == "pulse" and direction(p).value == d and fits(p) and gentle(p) and p.duration <= max_s
        ]
        cands.sort(key=intensity)
        if not cands or per_direction < 1:
            continue
        targets = np.unique(np.linspace(0, len(cands) - 1, per_direction).round().astype(int))
        used: set[int] = set()
        for k in targets:
            order = [j for j in range(k, -1, -1) if j not in used]  # the target, else the next gentler one
            for j in order:
                if cell is None or _in_window(cell, cands[j]):
                    used.add(j)
                    out.append(cands[j])
                    break
    return out


def _in_window(cell: Cell, prof: Any) -> bool:
    from battlab.simulation import simulate

    res = simulate(cell, prof, soc0=float(prof.soc0))
    v = res.voltage
    lo, hi = float(cell["V_min"]) + NOISE_MARGIN_V[0], float(cell["V_max"]) - NOISE_MARGIN_V[1]
    return res.ended_by is None and v.min() >= lo and v.max() <= hi


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


def design(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.design.workflow import design as design_plan
        from battlab.noise import NoiseModel

        grp = _read(ctx.path("groups", "groups"))["groups"]
        model = NoiseModel(**_read(ctx.path("noise", "model"))["model"])
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
        }
        figure = str(Path(rep.figure).resolve().relative_to(ctx.directory.resolve()))
        files = {"plan": "plan/plan.toml", "summary": "plan/plan.summary.json", "figure": figure}
        return StageOutput(files, out_summary)

    return run


def _profile_meta(m: Mapping[str, Any]) -> dict[str, Any]:
    return {k: m[k] for k in ("kind", "soc0", "duration") if k in m} | {"params": m.get("params")}


def experiments(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from protocols.library import Library

        n0 = len(camp.runs)
        lib = Library.load(ctx.path("library", "library"))
        cap = ctx.inputs["equilibrium"].summary["capacity_Ah"]  # SOC is defined on the equilibrium capacity
        ids = selected_ids(ctx.inputs["design"].summary)
        hours, logs, failed = 0.0, {}, {}
        for k, pid in enumerate(ids):
            ctx.progress(k, len(ids), f"profile {pid}")
            prof = lib[pid]
            hours += camp.run(P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient), f"oed/{pid}_prep").hours
            # a profile the cell cannot follow (a safety limit, a model failure of the virtual cell) is recorded
            # and left out of the fit; the others go on
            out = camp.run(camp.measurement(prof), f"oed/{pid}", must_complete=False)
            hours += out.hours
            if out.status == "completed":
                logs[str(pid)] = _rel(ctx, out.log_path)
            else:
                failed[str(pid)] = out.reason or out.status
        if not logs:
            raise RunFailed(f"no designed experiment completed ({'; '.join(f'{k}: {v}' for k, v in failed.items())})")
        files = {f"log_{k}": v for k, v in logs.items()}
        files["health"] = _health_file(camp, ctx, "experiments", n0)
        summary = {"profiles": ids, "completed": [int(k) for k in logs], "failed": failed, "hours": hours}
        return StageOutput(files, summary, hours)

    return run


def selected_ids(design_summary: dict[str, Any]) -> list[int]:
    """The distinct profiles a design selected, in group order."""
    out: list[int] = []
    for g in design_summary["groups"]:
        out += [int(p) for p in g["selected"] if int(p) not in out]
    return out


def fit_oed(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.identify import cumulative_fit
        from battlab.identify.fit import Stage as FitStage
        from battlab.noise import NoiseModel

        cell = Cell.load(str(ctx.path("equilibrium", "cell")))
        model = NoiseModel(**_read(ctx.path("noise", "model"))["model"])
        logs = {k.removeprefix("log_"): v for k, v in ctx.inputs["experiments"].files.items() if k.startswith("log_")}
        exps = {
            pid: D.experiment(ctx.directory / rel, cell, name=f"profile {pid}", noise=model)
            for pid, rel in logs.items()
        }
        stages, used = [], set()
        for g in ctx.inputs["design"].summary["groups"]:
            new = [str(p) for p in g["selected"] if str(p) not in used and str(p) in exps]
            used |= set(new)
            stages.append(FitStage(tuple(g["parameters"]), tuple(exps[p] for p in new)))
        out = ctx.directory / "fit"
        summary = cumulative_fit(cell, stages, camp, out / "oed.bpx.json", ctx.progress)
        return StageOutput({"cell": "fit/oed.bpx.json", "summary": "fit/oed.summary.json"}, summary)

    return run


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
        model = NoiseModel(**_read(ctx.path("noise", "model"))["model"])
        rates = camp.config.conventional.c_rates or (CONVENTIONAL_QUICK if camp.config.quick else CONVENTIONAL_FULL)
        hours, exps, files, notes = 0.0, [], {}, {}
        for k, c in enumerate(rates):
            ctx.progress(k, len(rates) + 1, f"{abs(c):.3g}C {'charge' if c > 0 else 'discharge'}")
            prep = (
                P.prepare_empty(camp.q_rated, camp.ambient)
                if c > 0
                else P.prepare(1.0, camp.q_rated, cap, camp.ambient)
            )
            hours += camp.run(prep, f"conventional/cc_{c:+.3g}C_prep").hours
            out = camp.run_to_limit(
                P.constant_current(c, camp.q_rated, camp.ambient, rest_after_s=camp.rest_after_s),
                f"conventional/cc_{c:+.3g}C",
                notes,
            )
            hours += out.hours
            files[f"log_cc_{c:+.3g}C"] = _rel(ctx, out.log_path)
            exps.append(D.experiment(out.log_path, cell, name=f"CC {c:+.3g}C", noise=model, dt=CC_DT))
        ctx.progress(len(rates), len(rates) + 1, "UDDS")
        udds = drive_profile(Cycle.UDDS, soc0=0.8, id="UDDS")
        hours += camp.run(P.prepare(0.8, camp.q_rated, cap, camp.ambient), "conventional/udds_prep").hours
        out = camp.run(camp.measurement(udds), "conventional/udds")
        hours += out.hours
        files["log_udds"] = _rel(ctx, out.log_path)
        exps.append(D.experiment(out.log_path, cell, name="UDDS", noise=model))
        fit_dir = ctx.directory / "conventional"
        summary = cumulative_fit(
            cell, [FitStage(tuple(NAMES), tuple(exps))], camp, fit_dir / "conventional.bpx.json", ctx.progress
        )
        summary["test_hours"] = hours
        summary["notes"] = notes
        files.update(cell="conventional/conventional.bpx.json", health=_health_file(camp, ctx, "conventional", n0))
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
        hours += camp.run(P.prepare(float(prof.soc0), camp.q_rated, cap, camp.ambient), "validation/drive_prep").hours
        out = camp.run(camp.measurement(prof), "validation/drive")
        hours += out.hours
        logs[f"{prof.params.get('name', 'drive')} from SOC {prof.soc0:g}"] = (out.log_path, 1.0)
        cells = {
            "nominal": Cell.load(str(ctx.path("equilibrium", "cell"))),
            "conventional": Cell.load(str(ctx.path("conventional", "cell"))),
            "OED": Cell.load(str(ctx.path("fit", "cell"))),
        }
        truth = Cell.load(camp.tester.truth) if camp.tester.virtual else None
        summary = score(logs, cells, truth, ctx.directory / "validation")
        summary["hours"] = hours
        summary["notes"] = notes
        files = {f"log_{k}": _rel(ctx, p) for k, (p, _) in logs.items()}
        files.update(summary="validation/validation.json", health=_health_file(camp, ctx, "validation", n0))
        return StageOutput(files, summary, hours)

    return run


def diagnosis(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.identify import residuals

        cell = Cell.load(str(ctx.path("fit", "cell")))
        logs = {
            k.removeprefix("log_"): ctx.directory / v
            for k, v in ctx.inputs["validation"].files.items()
            if k.startswith("log_")
        }
        summary = residuals(logs, cell, ctx.directory / "diagnosis")
        return StageOutput({"summary": "diagnosis/diagnosis.json"}, summary)

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


def report(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.report.campaign import write_report

        page = write_report(ctx.directory, {k: v.summary for k, v in ctx.inputs.items()}, ctx.inputs, camp)
        return StageOutput({"report": _rel(ctx, page)}, {"report": _rel(ctx, page)})

    return run


#: (name, title, needs) in order; the runner checks that each need comes before
ORDER: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("capacity_before", "capacity check (C/3 after CCCV)", ()),
    ("ocv", "OCV test (one C/20 cycle)", ()),
    ("equilibrium", "equilibrium fit", ("ocv",)),
    ("library", "input library", ()),
    ("sweep", "sensitivity sweep", ("library", "equilibrium")),
    ("groups", "parameter groups", ("sweep",)),
    ("noise", "repeated trials and noise model", ("library", "equilibrium")),
    ("design", "optimal designs per group", ("sweep", "groups", "noise")),
    ("experiments", "designed experiments on the tester", ("library", "design", "equilibrium")),
    ("fit", "cumulative fits with intervals", ("equilibrium", "noise", "design", "experiments")),
    ("conventional", "conventional baseline", ("equilibrium", "noise")),
    (
        "validation",
        "validation (nominal, conventional, OED)",
        ("library", "equilibrium", "conventional", "fit"),
    ),
    ("diagnosis", "diagnosis (residual analysis)", ("fit", "validation")),
    ("capacity_after", "capacity check again", ()),
    ("export", "BPX export", ("fit",)),
    ("report", "report.html", ()),
)
STAGE_NAMES = tuple(n for n, _, _ in ORDER)

_FUNCS: dict[str, Callable[[Campaign], Callable[[StageContext], StageOutput]]] = {
    "capacity_before": lambda c: capacity(c, "before"),
    "ocv": ocv,
    "equilibrium": equilibrium,
    "library": library,
    "sweep": sweep,
    "groups": groups,
    "noise": noise,
    "design": design,
    "experiments": experiments,
    "fit": fit_oed,
    "conventional": conventional,
    "validation": validation,
    "diagnosis": diagnosis,
    "capacity_after": lambda c: capacity(c, "after"),
    "export": export,
    "report": report,
}


def stages(camp: Campaign) -> list[Stage]:
    """The campaign's stages with their settings (what decides a rerun) and needs; ``[stages] skip`` leaves stages
    out (and every stage that needs one of them). The report needs every stage before it."""
    cfg = camp.config.as_dict()
    skip = set(camp.config.stages.skip)
    settings = {
        "capacity_before": {"campaign": cfg["campaign"]},
        "ocv": {"campaign": cfg["campaign"]},
        "library": {"library": cfg["library"]},
        "sweep": {"quick": camp.config.quick},
        "groups": {"design": cfg["design"]},
        "noise": {"noise": cfg["noise"]},
        "design": {"design": cfg["design"]},
        "fit": {"fit": cfg["fit"]},
        "experiments": {"rest_after_s": camp.rest_after_s},
        "validation": {"rest_after_s": camp.rest_after_s, "quick": camp.config.quick, "set": cfg["validation"]},
        "conventional": {
            "fit": cfg["fit"],
            "quick": camp.config.quick,
            "rest_after_s": camp.rest_after_s,
            "set": cfg["conventional"],
        },
        "capacity_after": {"campaign": cfg["campaign"]},
    }
    out: list[Stage] = []
    for name, title, needs in ORDER:
        if name in skip or any(n in skip for n in needs):
            skip.add(name)
            continue
        if name == "report":
            needs = tuple(s.name for s in out)
        if name == "capacity_after":  # after every run of the campaign
            needs = tuple(s.name for s in out if s.name in ("experiments", "conventional", "validation", "noise"))
        out.append(Stage(name, _FUNCS[name](camp), needs, settings.get(name, {}), title))
    return out
