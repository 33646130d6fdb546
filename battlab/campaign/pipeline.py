"""The campaign's stages, in order, as functions registered with the stage runner (:mod:`battlab.campaign.stages`).

capacity check → OCV test → equilibrium fit → library → sensitivity sweep → groups → repeated trials and the
noise model → designs per group → the designed experiments on the tester → cumulative fits with intervals →
conventional baseline (its tests on the tester, fitted the same way) → validation (held-out tests on the tester;
nominal vs conventional vs OED) → diagnosis (residual analysis) → capacity check again → BPX export → report.

Each stage writes its artefacts under the campaign directory and returns its files, a JSON summary and the lab
hours it used. Runs on the tester are logged under ``runs/``; a run that does not complete fails its stage.
"""

from __future__ import annotations

from collections.abc import Callable

from battlab.campaign.assessment import conventional, diagnosis, export, fit_oed, report, validation
from battlab.campaign.characterisation import capacity, equilibrium, noise, ocv
from battlab.campaign.context import Campaign
from battlab.campaign.experiment_design import design, experiments, groups, library, sweep
from battlab.campaign.stages import Stage, StageContext, StageOutput

__all__ = ["ORDER", "STAGE_NAMES", "Campaign", "stages"]


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
