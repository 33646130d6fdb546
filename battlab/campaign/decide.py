"""Experiments that decide: when a diagnosis cannot tell two causes apart, design the experiment that best separates
their fitted models (:mod:`battlab.design.discriminate`), run it on the lab (the runner's safety, logging and resume,
as for any run), add its log to the data and diagnose again, until one cause wins or the budget of lab hours is
spent. Each round (the pair, the experiment chosen, its expected divergence and lab hours, the ranking after it) is
kept for the report.

The first diagnosis holds out what its options say; each later one holds out the new log (the last data file): both
candidates are fitted on the data so far, and the one that predicts the deciding experiment is named by the
diagnosis's own held-out rule.

A cause the diagnosis could not fit apart from base parameters that mimic it (``undetectable`` with ``hidden_by``:
not ruled out at any size, e.g. a series resistance taken up by the film resistances at one ambient) is decided the
same way when it declares what separates it from the cause owning those parameters (:func:`not_ruled_out`): the
candidates are the cell with the cause at its typical size (nothing refitted) and the cell whose owner's parameters
refit to mimic it (the T-criterion's linearised refit, on the experiment and on the same profile at the cell's
reference temperature, where the data were taken), so the experiment chosen is where no refit of the base can take
the cause up. Its log is then held out by its final part only (the fits see its beginning: what only it shows
must be fitted before it can be predicted).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from battlab import causes
from battlab.cell import Cell
from battlab.diagnose.report import DiagnosisReport
from battlab.diagnose.workflow import DiagnoseOptions, diagnose
from battlab.progress import Reporter, Subscriber
from protocols.errors import InputError

#: ambients the chamber reaches [degC] unless a range is given
AMBIENTS_DEGC = (10.0, 25.0, 40.0)
#: library profiles weighed per kind of evidence (spread over the library's ids)
PER_KIND = 12
#: the longest profile weighed [s]
MAX_PROFILE_S = 3600.0


@dataclass(frozen=True)
class DecideOptions:
    """Where deciding experiments run: instrument URLs (``virtual``: the in-process virtual tester, whose hidden cell
    is ``truth``), the lab hours they may take, the ambients the chamber reaches [degC] (one only: a bench without
    a chamber range), where their logs go."""

    diagnosis: DiagnoseOptions
    runs: Path
    cycler: str = "virtual"
    chamber: str = "virtual"
    truth: str | None = None
    budget_hours: float = 24.0
    ambients_degC: tuple[float, ...] = AMBIENTS_DEGC
    max_rounds: int = 3

    def __post_init__(self) -> None:
        if self.budget_hours <= 0:
            raise InputError(f"--budget-hours {self.budget_hours:g}: give the lab hours the experiments may take")
        if (self.cycler == "virtual") != (self.chamber == "virtual"):
            raise InputError("--decide: give both instruments as 'virtual' or both as URLs")
        if self.cycler == "virtual" and not self.truth:
            raise InputError("--decide on the virtual tester needs its hidden cell: --truth CELL")


@dataclass
class Decided:
    """The last diagnosis and every deciding round before it."""

    report: DiagnosisReport
    rounds: list[dict[str, Any]] = field(default_factory=list)
    undecided: str | None = None  # why the rounds stopped without a cause


def fitted_models(rep: DiagnosisReport, group: Sequence[str], cell: Cell) -> dict[str, tuple[Cell, tuple[str, ...]]]:
    """Each cause of ``group`` as the diagnosis fitted it: the cell (its extension on) at the fitted values, and the
    parameters its fit moves."""
    out = {}
    for c in rep.confirmations:
        if c.cause in group:
            model = cell.with_extension(c.cause) if causes.cause(c.cause).extension is not None else cell
            out[c.cause] = (model.with_values(**c.values), tuple(c.names))
    return out


@dataclass(frozen=True)
class Hidden:
    """A cause not ruled out because base parameters take it up (``by``, owned by ``owner``) at its ``typical``
    size."""

    cause: str
    owner: str
    by: tuple[str, ...]
    typical: dict[str, float]


def not_ruled_out(summary: dict[str, Any]) -> Hidden | None:
    """The first cause of a diagnosis ``summary``'s ``undetectable`` list hidden behind base parameters of another
    cause that it declares a separating experiment for (:attr:`battlab.causes.cause.Cause.separates`)."""
    for entry in summary.get("undetectable", []):
        key, by = entry.get("cause"), tuple(entry.get("hidden_by") or ())
        if not by or key not in causes.KEYS or causes.cause(key).extension is None:
            continue
        owners = [o.key for o in (causes.owner(n) for n in by) if o is not None and o.key != key]
        owner = next((o for o in owners if o in causes.cause(key).separates), None)
        if owner is not None and entry.get("typical"):
            return Hidden(key, owner, by, {n: float(v) for n, v in entry["typical"].items()})
    return None


def hidden_models(h: Hidden, cell: Cell) -> dict[str, tuple[Cell, tuple[str, ...]]]:
    """The candidates for a :class:`Hidden` cause: the cell with it at its typical size (nothing refitted: a nested
    alternative, which refitting its own parameters would turn back into the base), and the cell as it is, refitting
    the owner's parameters among the 18 with those that hide the cause."""
    from battlab.parameters import NAMES

    names = tuple(dict.fromkeys(n for n in (*causes.cause(h.owner).base, *h.by) if n in NAMES))
    return {h.cause: (cell.with_extension(h.cause, **h.typical), ()), h.owner: (cell, names)}


def candidate_profiles(group: Sequence[str]) -> list[Any]:
    """Library profiles of the kinds the causes' evidence names, spread over the library (:data:`PER_KIND` each)."""
    from protocols.library import Library

    lib = Library.build()
    kinds = dict.fromkeys(causes.cause(k).informed_by.kind for k in group)
    out = []
    for kind in kinds:
        pool = [p for p in lib if p.kind == kind and float(p.t[-1] - p.t[0]) <= MAX_PROFILE_S]
        step = max(1, len(pool) // PER_KIND)
        out += pool[::step][:PER_KIND]
    return out


def run_experiment(o: DecideOptions, profile: Any, ambient_degC: float, rel: str, cell: Cell) -> Path:
    """Prepare the cell (full charge, discharge to the profile's start SOC, rest) and measure the profile at
    ``ambient_degC`` on the lab, as one run (its log starts at the full charge: :func:`battlab.campaign.plans.
    prepared_measurement`); returns the log."""
    from battlab.campaign import plans as P
    from battlab.campaign.tester import Tester, VirtualBench, run_plan

    tester = Tester(o.cycler, o.chamber, truth=o.truth or "nca18650-true")
    bench = VirtualBench(tester, ambient_degC) if tester.virtual else None
    q = float(cell["Q_nom"])
    o.runs.mkdir(parents=True, exist_ok=True)
    checked = o.runs / "cell.bpx.json"  # the cell the plans are checked against (its window and limits)
    if not checked.exists():
        cell.to_bpx(checked)
    plan = P.prepared_measurement(profile, q, float(cell.capacity()), ambient_degC)
    out = run_plan(plan, tester, o.runs / f"{rel}.h5", cell=str(checked), bench=bench)
    if out.status != "completed":
        raise InputError(f"deciding experiment {rel} {out.status}: {out.reason}")
    return out.log_path


def decide(o: DecideOptions, subscribers: Sequence[Subscriber] = ()) -> Decided:
    """Diagnose; while the data cannot tell a group of causes apart and lab hours are left, design, run and add the
    experiment that separates them, and diagnose again (see the module docstring)."""
    from battlab.design.discriminate import T_ENOUGH, discriminate

    say = Reporter("decide", subscribers)
    data = list(o.diagnosis.data)
    cell = o.diagnosis.cell if isinstance(o.diagnosis.cell, Cell) else Cell.load(o.diagnosis.cell)
    spent, rounds = 0.0, []
    for k in range(o.max_rounds + 1):
        # the data's own held-out part first, then each deciding experiment's log
        held = (data[-1],) if rounds else o.diagnosis.held_out
        tail = bool(rounds) and bool(rounds[-1].get("not_ruled_out"))
        rep = diagnose(replace(o.diagnosis, data=tuple(data), held_out=held, held_out_tail=tail), subscribers)
        s = rep.summary
        if rounds:  # what the last deciding experiment changed
            rounds[-1]["cause_after"] = s["cause"]
            rounds[-1]["ranking_after"] = [r["cause"] for r in s["ranking"]]
            rounds[-1]["cannot_tell_after"] = [c.get("causes", [c["cause"]]) for c in s["cannot_tell"]]
        group = next((c["causes"] for c in s["cannot_tell"] if len(c.get("causes", [])) > 1), None)
        hidden = not_ruled_out(s) if group is None and s["cause"] is None and not rounds else None
        if hidden is not None:
            group = [hidden.cause, hidden.owner]
        if s["cause"] is not None or group is None:
            return Decided(rep, rounds)
        if len(o.ambients_degC) < 2 and any(
            "temperature" in causes.cause(g).separates.get(h, "") for g in group for h in group
        ):
            why = f"{' and '.join(group)} differ in their temperature dependence: a chamber range for a second ambient"
            return Decided(rep, rounds, f"cannot tell {' from '.join(group)} on one ambient; needs {why}")
        if k == o.max_rounds:
            return Decided(rep, rounds, f"{o.max_rounds} deciding experiments did not separate {', '.join(group)}")
        say("note", text=f"designing the experiment that tells {' from '.join(group)}")
        models = hidden_models(hidden, rep_cell(cell)) if hidden else fitted_models(rep, group, rep_cell(cell))
        disc = discriminate(
            models,
            candidate_profiles(group),
            [a + 273.15 for a in o.ambients_degC],
            budget_hours=o.budget_hours - spent,
            anchor=float(cell["T_ref"]) if hidden else None,
        )
        if disc.chosen is None or (hidden and disc.chosen.divergence < T_ENOUGH):
            return Decided(rep, rounds, _nothing_separates(hidden, disc))
        c = disc.chosen
        say("note", text=f"running profile {c.profile_id} at {c.ambient - 273.15:.0f} degC ({c.hours:.1f} lab h)")
        from protocols.library import Library

        profile = Library.build()[int(c.profile_id)]
        log = run_experiment(o, profile, c.ambient - 273.15, f"decide_{k + 1}_{c.profile_id}", cell)
        spent += c.hours
        data.append(log)
        rounds.append(
            {
                "round": k + 1,
                "causes": list(group),
                "experiment": {
                    "profile": c.profile_id,
                    "ambient_degC": c.ambient - 273.15,
                    "divergence": c.divergence,
                    "lab_hours": c.hours,
                    "log": str(log),
                },
                "design": disc.summary(),
                "ranking_before": [r["cause"] for r in s["ranking"]],
                **(
                    {
                        "not_ruled_out": {
                            "cause": hidden.cause,
                            "hidden_by": list(hidden.by),
                            "owner": hidden.owner,
                            "typical": hidden.typical,
                        }
                    }
                    if hidden
                    else {}
                ),
            }
        )
    raise AssertionError("unreachable")


def _nothing_separates(hidden: Hidden | None, disc: Any) -> str:
    """Why no deciding experiment runs: nothing feasible, or (for a cause not ruled out) nothing that reaches
    :data:`battlab.design.discriminate.T_ENOUGH`, with the best there was."""
    from battlab.design.discriminate import T_ENOUGH

    if hidden is None:
        return "no experiment within the budget and the limits separates them"
    c = disc.chosen
    best = (
        f"best: χ² {c.divergence:.3g} for profile {c.profile_id} at {c.ambient - 273.15:.0f} degC"
        if c is not None
        else "every candidate would pass a limit or the budget"
    )
    return (
        f"{hidden.cause} is not ruled out (hidden behind {', '.join(hidden.by)}), and no experiment within the budget "
        f"and the limits separates it at its typical size from the parameters of {hidden.owner} refitted (χ² below "
        f"{T_ENOUGH:g}; {best})"
    )


def rep_cell(cell: Cell) -> Cell:
    """The diagnosis's base cell (its extensions off): the fitted values are relative to it."""
    for key in list(cell.extensions):
        cell = cell.without_extension(key)
    return cell


__all__ = [
    "AMBIENTS_DEGC",
    "DecideOptions",
    "Decided",
    "Hidden",
    "candidate_profiles",
    "decide",
    "fitted_models",
    "hidden_models",
    "not_ruled_out",
]
