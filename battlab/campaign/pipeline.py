"""The campaign's stages, in order, each one declared unit (:class:`battlab.campaign.unit.Unit`): what it needs,
the settings it reads, whether it uses the tester, the files it writes and its report section.

capacity check → OCV test → equilibrium fit → library → sensitivity sweep → groups → repeated trials and the
noise model → designs per group → the designed experiments on the tester → cumulative fits with intervals →
conventional baseline (its tests on the tester, fitted the same way) → validation (held-out tests on the tester;
nominal vs conventional vs OED) → diagnosis (name what the fit misses, decide, extend) → capacity check again →
BPX export → report.

Each stage writes its artefacts under the campaign directory and returns its files, a JSON summary and the lab
hours it used. Runs on the tester are logged under ``runs/``; a run that does not complete fails its stage. To add
a stage: write its function of the campaign (and its report section), and add one :class:`Unit` line below.
"""

from __future__ import annotations

from battlab.campaign import report as R
from battlab.campaign.assessment import conventional, export, fit_oed, validation
from battlab.campaign.characterisation import capacity, equilibrium, noise, ocv
from battlab.campaign.context import Campaign
from battlab.campaign.diagnosis import diagnosis
from battlab.campaign.experiment_design import design, experiments, groups, library, sweep
from battlab.campaign.stages import Stage, StageContext, StageOutput
from battlab.campaign.unit import Unit, resolve_needs

__all__ = ["STAGE_NAMES", "UNITS", "Campaign", "stages"]


def _report(camp: Campaign):  # noqa: ANN202 - the report stage of the units before it
    def run(ctx: StageContext) -> StageOutput:
        from battlab.campaign.context import rel_path

        page = R.write_report(ctx.directory, {k: v.summary for k, v in ctx.inputs.items()}, ctx.inputs, camp, UNITS)
        return StageOutput({"report": rel_path(ctx, page)}, {"report": rel_path(ctx, page)})

    return run


T = ("campaign",)  # every stage on the tester reads the cell's rating and the ambient
UNITS: tuple[Unit, ...] = (
    Unit(
        "capacity_before",
        "capacity check (C/3 after CCCV)",
        lambda c: capacity(c, "before"),
        (),
        T,
        True,
        ("log", "health"),
        R.capacity_before,
    ),
    Unit("ocv", "OCV test (one C/20 cycle)", ocv, (), T, True, ("log", "health")),
    Unit(
        "equilibrium",
        "equilibrium fit",
        equilibrium,
        ("ocv",),
        ("campaign", "quick"),
        False,
        ("cell", "screen_cell", "summary", "figure"),
        R.equilibrium,
    ),
    Unit("library", "input library", library, (), ("library",), False, ("library",)),
    Unit(
        "sweep",
        "sensitivity sweep",
        sweep,
        ("library", "equilibrium"),
        ("campaign", "quick"),
        False,
        ("store",),
        R.sweep,
    ),
    Unit("groups", "parameter groups", groups, ("sweep",), ("design",), False, ("groups", "ranking_figure"), R.groups),
    Unit(
        "noise",
        "repeated trials and noise model",
        noise,
        ("library", "equilibrium"),
        ("campaign", "noise"),
        True,
        ("model", "figure", "health"),
        R.noise,
    ),
    Unit(
        "design",
        "optimal designs per group",
        design,
        ("sweep", "groups", "noise"),
        ("design",),
        False,
        ("plan", "summary", "figure"),
        R.design,
    ),
    Unit(
        "experiments",
        "designed experiments on the tester",
        experiments,
        ("library", "design", "equilibrium"),
        ("campaign", "quick"),
        True,
        ("log_*", "prep_*", "health"),
    ),
    Unit(
        "fit",
        "cumulative fits with intervals",
        fit_oed,
        ("equilibrium", "noise", "design", "experiments"),
        ("fit",),
        False,
        ("cell", "summary"),
        R.parameters,
    ),
    Unit(
        "conventional",
        "conventional baseline",
        conventional,
        ("equilibrium", "noise"),
        ("campaign", "quick", "fit", "conventional"),
        True,
        ("log_*", "cell", "health"),
        R.conventional,
    ),
    Unit(
        "validation",
        "validation (nominal, conventional, OED)",
        validation,
        ("library", "equilibrium", "conventional", "fit"),
        ("campaign", "quick", "validation"),
        True,
        ("log_*", "prep_*", "summary", "health"),
        R.validation,
    ),
    Unit(
        "diagnosis",
        "diagnosis (what the fitted cell still misses, the deciding experiments, the extended cell)",
        diagnosis,
        ("ocv", "fit", "validation", "experiments", "noise"),
        ("campaign", "fit", "diagnosis"),
        True,
        ("summary", "report", "cell", "log_*"),
        R.diagnosis,
    ),
    Unit(
        "capacity_after",
        "capacity check again",
        lambda c: capacity(c, "after"),
        (),
        T,
        True,
        ("log", "health"),
        R.capacity,
        after_all="tester",
    ),
    Unit("export", "BPX export", export, ("fit",), (), False, ("bpx",), R.export),
    Unit("report", "report.html", _report, (), ("campaign", "quick", "stages"), False, ("report",), after_all="all"),
)
STAGE_NAMES = tuple(u.name for u in UNITS)


def stages(camp: Campaign) -> list[Stage]:
    """The campaign's runnable stages; ``[stages] skip`` leaves stages out (and every stage that needs one)."""
    skip = set(camp.config.stages.skip)
    units = {u.name: u for u in UNITS}
    out: list[Stage] = []
    for u in UNITS:
        if u.name in skip or any(n in skip for n in u.needs):
            skip.add(u.name)
            continue
        out.append(u.stage(camp, resolve_needs(u, out, skip, units)))
    return out
