"""The campaign's diagnosis stage: the mission's last step on the campaign's own data.

The OED fit's cell is diagnosed (:func:`battlab.diagnose.workflow.diagnose`) on the designed experiments' logs
(training) with the held-out validation drive cycle; when the data cannot tell causes apart and ``[diagnosis] decide``
is on, the experiment that separates them is designed, run on the tester and added (:mod:`battlab.campaign.decide`),
within ``budget_hours``. The named cause, or when none is named the causes whose fits predicted the held-out drive cycle
at least the naming margin better but fell short of its noise margin, then where the residual is far above the noise
those passing their score test (:func:`candidates`, at most :data:`MAX_EXTEND`), is then fitted (the extend step:
``battlab fit`` on the designed experiments and the deciding ones, the cause's extension on, its own parameters and then
the base moved from the OED fit's cell); so is a control, the OED fit's base alone refitted by as many evaluations. A
cause that changes what the slow (C/20) cycle measures (:attr:`battlab.causes.Cause.slow_cycle`: a current sensor's
offset moves the charge count the equilibrium stands on) starts its extend step from the equilibrium refitted from the
OCV test with it on (:func:`refit_equilibrium`), and the control then from the equilibrium refitted alone in the same
way. The cells are scored on every held-out validation log: the residual before and after, against the noise-free truth
on the virtual lab. A cause is kept only when its extended cell predicts those tests (never fitted, other profiles than
the diagnosis's held-out drive cycle) better by the diagnosis's own margin than the better of the OED cell and the
control, or, for a cause a deciding experiment told apart, no worse (:func:`kept`), its fit moved the extension from off
(:func:`left_off`) and no declared look-alike of it passed its score test too (:func:`rivals`: then the two are a
``cannot_tell`` pair); else the summary's ``cause`` is null, ``suggested`` says what the diagnosis named and the verdict
why it was not kept. The diagnosis's fits move a few parameters beside the cause's; the extend step refits the base with
it, which is what a cause the OED fit's base has partly taken up needs (a 12 mV graphite hysteresis: its diagnosis fit
won the drive cycle by 47 % at 3.0 standard errors, short of 4; extended, the validation tests went 20.91 -> 5.71 mV).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from battlab import causes
from battlab.campaign.context import Campaign, rel_path
from battlab.campaign.stages import StageContext, StageOutput
from battlab.cell import Cell
from battlab.diagnose.confirm import MIN_GAIN, S2_REFIT


def _validation_logs(ctx: StageContext) -> dict[str, tuple[Path, float]]:
    """The validation stage's logs: name → (path, resampling step [s]); constant-current tests at 10 s."""
    out = {}
    for k, v in ctx.inputs["validation"].files.items():
        if k.startswith("log_"):
            name = k.removeprefix("log_")
            out[name] = (ctx.directory / v, 10.0 if "discharge" in name else 1.0)
    return out


def _diagnose(
    camp: Campaign,
    ctx: StageContext,
    cell_path: Path,
    train: list[Path],
    held: Path,
    preps: tuple[tuple[Path, Path], ...],
) -> Any:
    """The diagnosis, each log started at its preparation's full charge (``preps``: (log, preparation's log)), with
    deciding experiments on the tester when asked: (report, rounds, why undecided)."""
    from battlab.campaign.decide import DecideOptions, decide
    from battlab.diagnose.workflow import DiagnoseOptions, diagnose

    cfg = camp.config.diagnosis
    # every preparation is the same full charge: it leaves the SOC the OED fit found (its start SOCs' mean)
    fitted = ctx.inputs["fit"].summary.get("start_soc") or {}
    full = sum(fitted.values()) / len(fitted) if fitted else 1.0
    options = DiagnoseOptions(
        (*train, held),
        cell_path,
        held_out=held,
        max_iter=cfg.max_evaluations,
        preparations=preps,
        full_charge_soc=full,
    )

    def show(ev: Any) -> None:
        if ev.kind == "note" and ev.text:
            ctx.progress(0, 0, ev.text)

    if not cfg.decide:
        return diagnose(options, [show]), [], None
    runs = ctx.directory / "runs" / "decide"
    dec = decide(
        DecideOptions(
            options,
            runs,
            camp.tester.cycler_url,
            camp.tester.chamber_url,
            camp.tester.truth if camp.tester.virtual else None,
            cfg.budget_hours,
            tuple(cfg.ambients_degC),
        ),
        [show],
    )
    return dec.report, dec.rounds, dec.undecided


#: the equilibrium cell's values a refit of the slow cycle changes (``A`` where the moles needed more room)
EQUILIBRIUM_VALUES = ("eps_s_n", "eps_s_p", "n_Li", "A")


def refit_equilibrium(
    camp: Campaign, ctx: StageContext, cause: str | None, out: Path
) -> tuple[dict[str, float], dict[str, Any]]:
    """The equilibrium refitted from the campaign's OCV test with ``cause``'s extension on and its slow-cycle
    parameters fitted beside the moles (:attr:`battlab.causes.Cause.slow_cycle`; None: the base cell), to the
    convergence of the full campaign's equilibrium stage; its report is written to ``out``. Returns the values it
    sets (:data:`EQUILIBRIUM_VALUES` and the cause's slow-cycle parameters) and a summary: the slow cycle's RMSE
    [mV], convergence, the capacity [Ah] and each slow-cycle parameter's estimate with its 95 % interval."""
    from battlab.campaign import data as D
    from battlab.campaign.characterisation import ocv_cycle
    from battlab.campaign.context import plain, write_json
    from battlab.identify.ocv_model import MAX_SIMULATIONS, NUISANCES, fit_equilibrium_model

    c = causes.cause(cause) if cause is not None else None
    extra = tuple(f"{c.key}.{n}" for n in c.slow_cycle) if c is not None else ()
    cell = camp.start.with_extension(c.key) if extra else camp.start
    eq = fit_equilibrium_model(
        ocv_cycle(D.load(ctx.path("ocv", "log"))),
        cell,
        nuisances=(*NUISANCES, *extra),
        max_simulations=MAX_SIMULATIONS,
        progress=lambda k, r, s: ctx.progress(k, MAX_SIMULATIONS, f"equilibrium with {cause}: {r:.3f} mV"),
    )
    write_json(out, plain(eq.report()))
    own = {n: eq.cell.value(n) for n in extra}
    fitted = {n: [v, *eq.ci95.get(n, (None, None))] for n, v in own.items()}
    summary = {
        "rmse_mV": eq.rmse_mV,
        "converged": eq.converged,
        "capacity_Ah": eq.estimates["capacity_Ah"],
        "fitted": fitted,
        "file": out.name,
    }
    return {**{n: float(eq.cell[n]) for n in EQUILIBRIUM_VALUES}, **own}, summary


def _extend(
    camp: Campaign,
    ctx: StageContext,
    cause: str | None,
    cell_path: Path,
    train: list[Path],
    preps: tuple[tuple[Path, Path], ...],
    out: Path,
    equilibrium: dict[str, float] | None = None,
) -> Path:
    """The extend step: the named cause's extension switched on in the OED fit's cell and fitted on ``train`` (the
    designed experiments, with their preparations ``preps``, and the deciding ones) in two stages: its own
    parameters (:func:`battlab.diagnose.confirm.mechanism_names`) alone, then with every base parameter the OED fit
    moved (the base had taken up what the cause explains: on a truth with a 12 mV graphite hysteresis the cause's
    parameters alone left the 1C validation discharge at 40 mV). ``cause`` None: the control, the base alone refitted
    in two stages of the same evaluations (what as many evaluations do without the cause). ``equilibrium``: values
    the cell starts from instead of the OED cell's (:func:`refit_equilibrium`)."""
    from battlab.diagnose.confirm import mechanism_names
    from battlab.identify.fit_options import FitOptions
    from battlab.identify.workflow import fit

    cell = Cell.load(str(cell_path))
    c = causes.cause(cause) if cause is not None else None
    start = cell.with_extension(c.key) if c is not None and c.extension is not None else cell
    if equilibrium:
        start = start.with_values(**equilibrium)
    names = tuple(mechanism_names(start, c.key, c.qualified_names)) if c is not None else ()
    base = tuple(n for n in ctx.inputs["fit"].summary.get("parameters", {}) if n not in names)
    # every experiment in each stage; the control spends the same two stages of evaluations on the base alone
    groups = ((names, frozenset()), ((*base, *names), frozenset())) if names else ((base, frozenset()),) * 2
    options = FitOptions(
        data=tuple(train),
        cell=start,
        groups=groups,
        noise=ctx.path("noise", "model"),
        max_iter=camp.config.diagnosis.max_evaluations * 2,
        polish=camp.config.fit.polish,
        preparations=preps,
        output=out,
        drop_uninformed=True,
    )
    fit(options)
    return out


#: at most this many causes are extended and scored on the validation tests when the diagnosis names none
MAX_EXTEND = 2


def candidates(summary: dict[str, Any]) -> list[str]:
    """The causes to extend: the one the diagnosis named; else those whose fits predicted the held-out data at least
    :data:`battlab.diagnose.confirm.MIN_GAIN` better than its baseline (``held_out_metric`` against
    ``extension_gain.metric_before``) without clearing the noise margin, the best first; then, where the residual is
    far above the noise (s² above :data:`battlab.diagnose.confirm.S2_REFIT`), the causes with an extension that pass
    their score test, the strongest first (the diagnosis's fits move the cause's parameters from the OED fit's cell,
    whose base has taken up what the cause explains: a truth cooled 1.5 times better than its file leaves s² 800 and
    the thermal fit alone cannot undo the base's compensation); at most :data:`MAX_EXTEND` in all."""
    if summary["cause"] is not None:
        return [summary["cause"]]
    gains = _held_out_gains(summary)
    out = sorted((k for k, g in gains.items() if g >= MIN_GAIN), key=lambda k: -gains[k])
    if (summary.get("residual_over_noise") or 0.0) > S2_REFIT:
        scored = sorted((r for r in summary.get("ranking", []) if r.get("passes")), key=lambda r: r["p_value"])
        out += [r["cause"] for r in scored if r["cause"] not in out and causes.cause(r["cause"]).extension is not None]
    return out[:MAX_EXTEND]


def _held_out_gains(summary: dict[str, Any]) -> dict[str, float]:
    """Per cause the diagnosis fitted: its fit's held-out gain over the baseline (noise-normalised errors)."""
    ref = summary["extension_gain"].get("metric_before")
    if not ref:
        return {}
    return {
        c["cause"]: 1.0 - c["held_out_metric"] / ref
        for c in summary["confirmations"]
        if c["cause"] != "base" and c.get("held_out_metric") is not None
    }


#: an extension whose every sized parameter ends within this fraction of its typical size from "off" was left off by
#: its fit: a gain of that cell is the base's refit, not the cause (on a truth without a hidden effect the thermal
#: extension ended 0.2-4.6 % of its typical sizes from off while its extended cell won the validation tests by 52 %)
NEGLIGIBLE = 0.1


def left_off(cell: Cell, key: str) -> str | None:
    """Why ``cell``'s extension ``key`` is effectively off (each parameter with a typical size within
    :data:`NEGLIGIBLE` of it from its off value), else None; None too for a cause without sized parameters."""
    c = causes.cause(key)
    values = cell.extensions.get(key, {})
    moved = {
        p.name: abs(float(values.get(p.name, p.off)) - p.off) / p.typical
        for p in c.parameters
        if p.typical is not None and p.typical > 0
    }
    if not moved or max(moved.values()) >= NEGLIGIBLE:
        return None
    top = sorted(moved.items(), key=lambda kv: -kv[1])[:3]
    sizes = ", ".join(f"{n} {100 * v:.1f} %" for n, v in top)
    return f"its fit left {key} at off (at most {sizes} of the typical sizes)"


def base_did_it(key: str, row: dict[str, Any]) -> str | None:
    """Why the extended cell's gain is its base's refit, not the cause's, else None: the same cell with the
    extension switched off (``row["rmse_off_mV"]``, nothing refitted) predicts the validation tests within the
    naming margin (:data:`battlab.diagnose.confirm.MIN_GAIN`) of the extended cell. On a truth without a hidden effect
    a thermal extension with an entropic offset of 7 µV/K (14 % of its typical size) won them 1.83 -> 1.20 mV against
    the OED cell; switched off, the cause's own part is what is left."""
    after, off = row.get("rmse_after_mV"), row.get("rmse_off_mV")
    if after is None or off is None or after <= (1.0 - MIN_GAIN) * off:
        return None
    return (
        f"the extended cell with {key} switched off predicts them {off:.2f} mV against {after:.2f} mV with it on "
        f"(not {100 * MIN_GAIN:.0f} % better with it): the gain is the base's refit"
    )


def rivals(key: str, summary: dict[str, Any], rejected: set[str]) -> list[str]:
    """The declared look-alikes of ``key`` (:attr:`battlab.causes.cause.Cause.separates`) that passed their score
    test on the diagnosis's data and were not extended and rejected: with them the data cannot tell which one the
    extended cell's gain stands for (lithium lost during the tests shifts the windows as an OCP shift does)."""
    passed = {r["cause"] for r in summary.get("ranking", []) if r.get("passes")}
    return [k for k in causes.cause(key).separates if k in passed and k not in rejected]


def _pair_verdict(key: str, pair: list[str], row: dict[str, Any], diagnosis: str) -> str:
    """The verdict for an extended cell that wins the validation tests while a look-alike of its cause passes its
    score test too."""
    others = ", ".join(pair)
    return (
        f"cannot tell {key} from {others}: the cell extended with {key} predicts the validation tests "
        f"{row['rmse_before_mV']:.2f} -> {row['rmse_after_mV']:.2f} mV (against the {row['baseline']}), but {others} "
        f"passes its score test too; told apart by {causes.cause(key).separates[pair[0]]}. The diagnosis: {diagnosis}"
    )


def judge(
    key: str, row: dict[str, Any], extended: Cell, summary: dict[str, Any], rejected: set[str], rounds: bool
) -> tuple[str | None, str, dict[str, Any] | None]:
    """One extended cause judged on its validation row (:func:`kept`), its fitted extension (:func:`left_off`), its
    own part of the gain (:func:`base_did_it`) and its look-alikes (both unless a deciding experiment (``rounds``)
    named it, whose evidence the validation tests at one ambient cannot show): the cause kept or None, the
    verdict, and the ``cannot_tell`` entry when it is a pair. ``summary``: the diagnosis's; ``rejected``: the causes
    already extended and not kept."""
    by_diagnosis = key == summary["cause"]
    told_apart = rounds and by_diagnosis  # a deciding experiment told it from its look-alikes
    named, why = kept(key, summary["verdict"], row, told_apart, by_diagnosis)
    if named is None:
        return None, why, None
    if (off := left_off(extended, key)) is not None:
        why = (
            f"not confirmed: {key}: the cell extended with it predicts the validation tests "
            f"{row['rmse_before_mV']:.2f} -> {row['rmse_after_mV']:.2f} mV, but {off}: the gain is the base's "
            f"refit. The diagnosis: {summary['verdict']}"
        )
        return None, why, None
    if not told_apart and (base := base_did_it(key, row)) is not None:
        why = (
            f"not confirmed: {key}: the cell extended with it predicts the validation tests "
            f"{row['rmse_before_mV']:.2f} -> {row['rmse_after_mV']:.2f} mV, but {base}. The diagnosis: "
            f"{summary['verdict']}"
        )
        return None, why, None
    if pair := ([] if told_apart else rivals(key, summary, rejected)):
        why = _pair_verdict(key, pair, row, summary["verdict"])
        told = causes.cause(key).separates[pair[0]]
        return None, why, {"causes": [key, *pair], "cause": key, "why": why, "experiment": told}
    return named, (why if by_diagnosis else _unnamed_but_kept(key, summary, row)), None


def look_alikes(key: str) -> str:
    """What else a kept cause's extended cell is consistent with, and what tells them apart (the cause's declared
    :attr:`battlab.causes.cause.Cause.separates`), as a sentence for its verdict; empty when none is declared."""
    alike = causes.cause(key).separates
    if not alike:
        return ""
    return " Also consistent with " + "; ".join(f"{k}, told apart by {how}" for k, how in alike.items()) + "."


#: a cause named after a deciding experiment is kept when the extended cell predicts the validation tests no worse
#: than this (relative mean RMSE)
NO_WORSE = 0.1


def kept(
    cause: str | None, verdict: str, gain: dict[str, Any], decided: bool = False, named: bool = True
) -> tuple[str | None, str]:
    """The named cause and the verdict, kept when the cell extended with it predicts the validation tests (never
    fitted, other profiles than the diagnosis's held-out drive cycle) better by the diagnosis's own margin
    (:data:`battlab.diagnose.confirm.MIN_GAIN` on the mean RMSE ``gain``); else no cause, and why. On a truth without
    a hidden effect an equilibrium shift won the drive cycle by 32 % (0.44 -> 0.30 mV) and took the validation tests
    from 0.92 to 19.09 mV once extended. A cause named by a deciding experiment (``decided``: its evidence is that
    experiment's held-out part, e.g. at another ambient, where the validation tests at the campaign's ambient cannot
    show what told it from its look-alike) is kept when the validation tests get no worse (:data:`NO_WORSE`).
    ``named``: the diagnosis named the cause (else it was extended to check a fit that won the held-out data short of
    the noise margin, or a score test passed on a residual far above the noise). ``gain["rmse_before_mV"]`` is the
    baseline's: the better of the OED cell and its base refitted alone by the same evaluations (``gain["baseline"]``),
    so that what more evaluations alone do is not taken for the cause."""
    before, after = gain.get("rmse_before_mV"), gain.get("rmse_after_mV")
    if cause is None or before is None or after is None:
        return cause, verdict
    if after <= (1.0 - MIN_GAIN) * before or (decided and after <= (1.0 + NO_WORSE) * before):
        return cause, verdict
    need = f"no more than {100 * NO_WORSE:.0f} % worse" if decided else f"not {100 * MIN_GAIN:.0f} % better"
    against = f", against the {gain['baseline']}" if gain.get("baseline") else ""
    return None, (
        f"not confirmed: {'the diagnosis named ' if named else ''}{cause}"
        f"{'' if named else ' (extended though the diagnosis did not name it)'}"
        f", but the cell extended with it predicts the validation tests {before:.2f} -> {after:.2f} mV ({need}"
        f"{against}); the cell is left as fitted. The diagnosis: {verdict}"
    )


def _unnamed_but_kept(key: str, summary: dict[str, Any], row: dict[str, Any]) -> str:
    """The verdict for a cause the diagnosis did not name that the extend step keeps: its fit won the held-out data
    by the margin short of the noise margin, or it passed its score test where the residual is far above noise."""
    won = (
        f"the {row['baseline']} ({row['rmse_before_mV']:.2f} -> {row['rmse_after_mV']:.2f} mV; OED cell "
        f"{row['rmse_oed_mV']:.2f}, its base refitted alone {row['rmse_refit_mV']:.2f})"
    )
    g = _held_out_gains(summary).get(key)
    if g is not None and g >= MIN_GAIN:
        fit = next(c for c in summary["confirmations"] if c["cause"] == key)
        why = (
            f"its diagnosis fit predicted the held-out data {100 * g:.0f} % better than the "
            f"{summary['extension_gain']['baseline']} at {fit['z_vs_baseline']:.1f} standard errors (short of the "
            "noise margin that names it there)"
        )
    else:
        p = next((r["p_value"] for r in summary.get("ranking", []) if r["cause"] == key), float("nan"))
        why = (
            f"it passes its score test (p {p:.2g}) on a residual far above the noise "
            f"(s² {summary.get('residual_over_noise', float('nan')):.3g}), though its diagnosis fit from the OED "
            "cell did not win the held-out data"
        )
    return (
        f"{key}: {why}; extended with its base refitted, it predicts the validation tests better than {won}. "
        f"The diagnosis: {summary['verdict']}"
    )


def diagnosis(camp: Campaign) -> Callable[[StageContext], StageOutput]:
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.assessment import experiment_logs
        from battlab.campaign.identify import score

        cell_path = ctx.path("fit", "cell")
        train, preps = experiment_logs(ctx)
        logs = _validation_logs(ctx)
        drive_name = next((name for name in logs if "discharge" not in name), None)
        drive = logs[drive_name][0] if drive_name is not None else None
        out = ctx.directory / "diagnosis"
        out.mkdir(parents=True, exist_ok=True)
        if drive is None:
            raise ValueError("campaign diagnosis: the validation stage logged no drive cycle to hold out")
        vfiles = ctx.inputs["validation"].files
        drive_prep = ctx.directory / vfiles[f"prep_{drive_name}"] if f"prep_{drive_name}" in vfiles else None
        held_prep = ((drive, drive_prep),) if drive_prep is not None else ()
        rep, rounds, undecided = _diagnose(camp, ctx, cell_path, train, drive, preps + held_prep)
        s = rep.summary
        s["rounds"] = rounds
        if undecided:
            s["undecided"] = undecided
        rep.write(out / "report")
        files = {"summary": "diagnosis/diagnosis.json", "report": "diagnosis/report/report.html"}
        for r in rounds:
            files[f"log_decide_{r['round']}"] = rel_path(ctx, Path(r["experiment"]["log"]))
        truth = Cell.load(camp.tester.truth) if camp.tester.virtual else None
        decided = [Path(r["experiment"]["log"]) for r in rounds]  # their logs start at their own full charge
        suggested, tried = s["cause"], []
        cause, verdict = None, s["verdict"]
        gain: dict[str, Any] = {"rmse_before_mV": None, "rmse_after_mV": None, "held_out": list(logs)}
        table: dict[str, Any] = {}
        before = Cell.load(str(cell_path))
        refit: Cell | None = None
        undecided_pairs: list[dict[str, Any]] = []
        keys = candidates(s)
        # a cause that changes the slow cycle is fitted with the equilibrium refitted: so is then the control
        slow = any(causes.cause(k).slow_cycle for k in keys)
        equilibria: dict[str, Any] = {}
        for k, key in enumerate(keys):
            if refit is None:
                ctx.progress(0, 0, "refitting the OED cell's base alone (the extend step's control)")
                eq = None
                if slow:
                    eq, equilibria["control"] = refit_equilibrium(camp, ctx, None, out / "refit.equilibrium.json")
                control = _extend(camp, ctx, None, cell_path, [*train, *decided], preps, out / "refit.bpx.json", eq)
                refit = Cell.load(str(control))
            ctx.progress(0, 0, f"extending the OED cell with {key} and scoring it on the validation tests")
            name = "extended.bpx.json" if k == 0 else f"extended_{key}.bpx.json"
            eq = None
            if causes.cause(key).slow_cycle:
                eq_file = out / name.replace(".bpx.json", ".equilibrium.json")
                eq, equilibria[key] = refit_equilibrium(camp, ctx, key, eq_file)
            extended = _extend(camp, ctx, key, cell_path, [*train, *decided], preps, out / name, eq)
            after = Cell.load(str(extended))
            # the extension switched off on the extended cell's base: what the cause's own part of the gain is
            cells = {"before": before, "refit": refit, "after": after, "extension off": after.without_extension(key)}
            rmse = score(logs, cells, truth, out / ("validation" if k == 0 else f"validation_{key}"))["rmse_mV"]
            mean = {c: sum(v.values()) / len(v) for c, v in rmse.items()}
            # the baseline: the better of the OED cell and its base refitted by the same evaluations
            ref = "refit" if mean["refit"] < mean["before"] else "before"
            row = {
                "cause": key,
                "rmse_before_mV": mean[ref],
                "rmse_after_mV": mean["after"],
                "baseline": "base refit" if ref == "refit" else "OED cell",
                "rmse_oed_mV": mean["before"],
                "rmse_off_mV": mean["extension off"],
                "rmse_refit_mV": mean["refit"],
                "cell": name,
            }
            named, why, pair = judge(key, row, cells["after"], s, {t["cause"] for t in tried}, bool(rounds))
            if pair is not None:
                undecided_pairs.append(pair)
            tried.append({**row, "kept": named is not None})
            if k == 0 or named is not None or pair is not None:
                gain.update({x: row[x] for x in ("rmse_before_mV", "rmse_after_mV", "baseline")}, cause=key)
                table, verdict, files["cell"] = rmse, why, f"diagnosis/{name}"
            if named is not None:
                cause = named
                verdict += look_alikes(named)
                break
            if pair is not None:
                break
        summary = {
            "method": "battlab diagnose on the designed experiments, the validation drive cycle held out"
            + (", deciding experiments on the tester" if camp.config.diagnosis.decide else "")
            + f"; the named cause (else up to {MAX_EXTEND} whose fits won the held-out drive cycle by "
            f"{100 * MIN_GAIN:.0f} % short of the noise margin, then those passing their score test where s² > "
            f"{S2_REFIT:g}) is extended and kept when its extended cell predicts the validation tests "
            f"{100 * MIN_GAIN:.0f} % better (mean RMSE) than the better of the OED cell and its base refitted alone "
            "by the same evaluations",
            "cause": cause,
            "suggested": suggested,
            "extended": tried,
            "how": s.get("how"),
            "verdict": verdict,
            "cannot_tell": [*s["cannot_tell"], *undecided_pairs],
            "rounds": rounds,
            "undecided": undecided,
            "diagnosis_gain": s["extension_gain"],
            "extension_gain": gain,
            "validation_rmse_mV": table,
            "equilibrium_refit": equilibria,
            "residual_over_noise": s["residual_over_noise"],
            "lab_hours": sum(r["experiment"]["lab_hours"] for r in rounds),
        }
        from battlab.campaign.context import write_json

        write_json(out / "diagnosis.json", summary)
        return StageOutput(files, summary, summary["lab_hours"])

    return run


__all__ = ["NO_WORSE", "base_did_it", "diagnosis", "kept"]
