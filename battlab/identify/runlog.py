"""A run log's structure for the fit: one experiment per executed profile step of the run's plan.

The runner logs, for every sample, the step execution (``Step Count / 1``), the step's 1-based position in the plan
(``Step Index / 1``) and the trial of a repeated profile (``Cycle Count / 1``), and stores the plan it ran in the
log's metadata (``meta["plan"]``, profiles inline). A run log read with its plan is therefore cut into the profile
steps it executed: each is an experiment of its own, named ``<log>:<profile id>`` (``t<trial>`` appended when the
plan repeats profiles; ``s<step>`` when a profile runs at several steps; ``#n`` when gaps split it), whose profile
carries the plan's ``library_id`` (and ``group`` from a step labelled 'group k: ...'), so that the design's groups
(the library ids each group selected) become the fit's stages. The steps that bring the cell to
each profile's start SOC (CCCV, rests) and the rest after it are not fitted.

Repeated trials: profile steps labelled 'noise: ...' (the noise trials ``battlab design --noise-trials`` puts at the
start of a plan) are tagged ``noise_trial`` and are not fitted; they, and the trials of a plan run with ``repeat`` >
1, carry a ``repeat_key`` shared by the trials of one profile, from which :func:`repeated_trials` gathers the
voltages that eq. 36 takes the noise level from.

Start state of a profile: the last step before it that sets the cell's state (:func:`state_steps`: a charge to V_max
that tapered, or a rest of at least 30 min, as the design's plans have before every profile) plus the charge passed
since (``Net Capacity / Ah``) over the cell's capacity; without such a step, the given ``soc0`` of the log's first
sample plus the charge passed; else, when the log starts at rest, the SOC whose OCV is its first voltage (as for
plain data: a measurement run right after its preparation); else an error naming the profile. That start is a
uniform cell, which a rest of 30 min after a partial discharge is not (the particles relax for hours). So where a
full charge (a charge to V_max that tapered) precedes the profile by at most :data:`LEAD_IN_MAX_S`, with no gap in
the log since, the experiment starts at the charge's end and replays the logged current through the preparation and
the rest into the profile (its ``lead_in``, in :data:`LEAD_IN_DT` s bins, simulated but never scored): the CV phase
leaves the cell nearly uniform, the simulation carries the gradients the preparation leaves. Its SOC there is the
profile's start SOC above minus the charge passed since the full charge (the taper to C/20 stops a few mV short of
equilibrium at V_max: measured on nca18650-true 0.993, not 1); a lead-in whose start SOC is not within
:data:`LEAD_IN_SOC_TOL` of 1 (the logged current does not explain the preparation) is not taken.

When the run was interrupted and resumed, a step executed more than once is taken from its last (complete)
execution.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import FULL_CHARGE, Experiment, experiments_from_data, state_steps
from battlab.io.logged import CYCLE, NET_CAPACITY, STEP, STEP_INDEX, SURFACE, LoggedData
from battlab.io.plan import DESIGN_GROUPS, DesignGroup, Plan, groups_from_dicts, label_groups
from battlab.noise import NoiseModel
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.protocol import ProfileStep

#: the label prefix of a plan's repeated noise trials
NOISE_LABEL = "noise"
#: [s] a full charge at most this long before a profile starts its lead-in (older ones: a uniform start)
LEAD_IN_MAX_S = 12 * 3600.0
#: a lead-in whose start SOC (the profile's start SOC minus the charge passed since the full charge) is further than
#: this from 1 is not taken (the logged current does not explain the preparation: another capacity, a missed step)
LEAD_IN_SOC_TOL = 0.05
#: [s] the lead-in's time step: charge-conserving bins; the profile keeps the fit's ``dt``
LEAD_IN_DT = 10.0


@dataclass(frozen=True)
class ProfileRun:
    """One executed profile step: its position in the plan (1-based), trial, profile id and rows [start, stop)."""

    step_index: int
    trial: int
    profile_id: str
    start: int
    stop: int
    group: int | None = None  # the design group of the step's label 'group k: ...'
    noise: bool = False  # a repeated noise trial (label 'noise: ...'), not fitted


def logged_plan(data: LoggedData) -> Plan | None:
    """The plan a run log was run from (its metadata), or None when it has none."""
    raw = data.meta.get("plan")
    if not isinstance(raw, dict) or "steps" not in raw:
        return None
    try:
        return Plan.from_dict(raw, source=f"{data.source or data.name} (the logged plan)")
    except InputError:
        return None


def has_structure(data: LoggedData) -> bool:
    """Whether the log has the runner's step columns."""
    return all(c in data.columns for c in (STEP, STEP_INDEX, CYCLE))


def profile_runs(data: LoggedData, plan: Plan) -> list[ProfileRun]:
    """The profile steps of ``plan`` executed in the log, in the order they ran (last execution of each)."""
    steps = plan.protocol.steps
    count, index, trial = (np.asarray(data.columns[c]) for c in (STEP, STEP_INDEX, CYCLE))
    edges = np.flatnonzero(np.diff(count) != 0) + 1
    starts = np.concatenate([[0], edges]).astype(int)
    stops = np.concatenate([edges, [len(data)]]).astype(int)
    found: dict[tuple[int, int], ProfileRun] = {}
    for a, b in zip(starts, stops, strict=True):
        j, tr = int(index[a]), int(trial[a])
        if not 1 <= j <= len(steps) or not isinstance(steps[j - 1], ProfileStep):
            continue
        m = re.match(r"group (\d+)\b", steps[j - 1].label or "")
        group = int(m.group(1)) if m else None
        noise = (steps[j - 1].label or "").lower().startswith(NOISE_LABEL)
        found[(j, tr)] = ProfileRun(j, tr, str(steps[j - 1].profile.id), int(a), int(b), group, noise)
    return sorted(found.values(), key=lambda r: r.start)


def check_same_plan(data: LoggedData, logged: Plan, given: Plan, given_name: str) -> None:
    """The plan given for the fit must hold the logged plan's profiles at the same steps."""
    where = data.source or data.name

    def ids(p: Plan) -> list[tuple[int, str]]:
        return [(k, str(s.profile.id)) for k, s in enumerate(p.protocol.steps, start=1) if isinstance(s, ProfileStep)]

    a, b = ids(logged), ids(given)
    if a != b:
        diff = next(((x, y) for x, y in zip(a, b, strict=False) if x != y), None)
        what = (
            f"step {diff[0][0]} runs profile {diff[0][1]} in the log, "
            f"step {diff[1][0]} profile {diff[1][1]} in the plan"
            if diff
            else f"{len(a)} profile steps in the log, {len(b)} in the plan"
        )
        raise InputError(f"{where}: the run's plan is not {given_name} ({what})")


def plan_experiments(
    data: LoggedData,
    cell: Cell,
    plan: Plan,
    *,
    dt: float = 1.0,
    noise: NoiseModel | None = None,
    soc0: float | None = None,
    max_gap: float = 60.0,
    rest_current: float | None = None,
    ambient: float | None = None,
) -> list[Experiment]:
    """The experiments of a run log cut at its plan's profile steps (see the module docstring)."""
    where = data.source or data.name
    runs = profile_runs(data, plan)
    if not runs:
        raise InputError(f"{where}: no profile step of its plan was run (nothing to fit)")
    i_rest = rest_current if rest_current is not None else 0.01 * float(cell["Q_nom"])
    states = state_steps(data, cell, i_rest)
    ah = data.columns.get(NET_CAPACITY)
    if ah is None:
        ah = np.concatenate([[0.0], np.cumsum(data.current[:-1] * np.diff(data.t))]) / 3600.0
    cap = cell.capacity()
    full = [s for s in states if s[2].startswith(FULL_CHARGE)]
    ids = [r.profile_id for r in runs]
    repeated = plan.options.repeat > 1
    out: list[Experiment] = []
    for r in runs:
        before = [s for s in states if s[0] <= r.start]
        if before:
            row, soc_set, _ = before[-1]
            start = soc_set + float(ah[r.start] - ah[row]) / cap
        elif soc0 is not None:
            start = soc0 + float(ah[r.start] - ah[0]) / cap
        elif abs(float(data.current[0])) <= i_rest:  # a log that starts at rest: the SOC of its first voltage
            lo, hi = float(cell.ocv(0.0)), float(cell.ocv(1.0))
            start = cell.soc_from_voltage(float(np.clip(data.voltage[0], lo, hi))) + float(ah[r.start] - ah[0]) / cap
        else:
            raise InputError(
                f"{where}: profile {r.profile_id} (plan step {r.step_index}) follows no full charge or rest of at "
                "least 30 min that sets the start state: give the SOC of the log's first sample (--soc0)"
            )
        name = f"{data.name}:{r.profile_id}"
        if ids.count(r.profile_id) > 1 and not repeated:
            name += f"s{r.step_index}"
        if repeated:
            name += f"t{r.trial}"
        sub = LoggedData(name, {c: v[r.start : r.stop] for c, v in data.columns.items()}, dict(data.meta), data.source)
        exps = experiments_from_data(
            sub,
            cell,
            dt=dt,
            noise=noise,
            soc0=float(np.clip(start, 0.0, 1.0)),
            max_gap=max_gap,
            rest_current=rest_current,
            ambient=ambient,
        )
        tags: dict[str, Any] = {
            "library_id": r.profile_id,
            "step_index": r.step_index,
            "trial": r.trial,
            "log_row": int(r.start),
        }
        if r.group is not None:
            tags["group"] = r.group
        if r.noise:
            tags["noise_trial"] = True
            tags["repeat_key"] = f"{data.name}:noise:{r.profile_id}"
        elif repeated:
            tags["repeat_key"] = f"{data.name}:step{r.step_index}"
        lead = [s for s in full if s[0] < r.start and data.t[r.start] - data.t[s[0]] <= LEAD_IN_MAX_S]
        a = lead[-1][0] if lead else 0
        soc_full = start - float(ah[r.start] - ah[a]) / cap
        if lead and abs(soc_full - 1.0) <= LEAD_IN_SOC_TOL and not np.any(np.diff(data.t[a : r.start + 1]) > max_gap):
            exps[0] = with_lead_in(exps[0], data, a, r.start, min(soc_full, 1.0))
        out += [replace(e, profile=e.profile.with_meta(params={**e.profile.params, **tags})) for e in exps]
    return out


def after_preparation(
    e: Experiment, prep: LoggedData, cell: Cell, full_soc: float = 1.0, log: LoggedData | None = None
) -> Experiment:
    """``e`` (a measurement that starts at rest, logged on its own) with its preparation, logged separately as
    ``prep`` (a run whose plan step 1 charges to full and step 2 rests; then the adjustment to the profile's start SOC
    and a rest), as its unscored lead-in (:func:`with_lead_in`): from the rest after the full charge through the
    adjustment and the rest, so that the gradients the adjustment leaves in the particles are simulated instead of
    taken as a uniform cell at rest (on nca18650-true, τ⁻ ≈ 4.3 h: after a 30 min rest a 0.2-SOC adjustment at C/2
    leaves s² 27 on a 30-min pulse profile, 541 after a 0.6-SOC one).

    Its start SOC is the full charge's, ``full_soc`` (a charge to V_max tapered below C/20: :func:`battlab.identify.
    experiments.state_steps`; 1 by definition, or what a fit found the same charge to leave), as for a run log that
    holds its preparation: the same for every model, where the SOC of ``e``'s
    rest voltage is not (a hysteresis of 12 mV puts the rest after a discharge 1.8 % of SOC low, which took up the
    hysteresis's offset and made its fit look worse than none). A preparation whose charge does not end full starts
    from ``e``'s rest-voltage SOC less the charge passed since. The rest voltage is itself still relaxing, so a fit
    frees the start SOC per experiment (:class:`battlab.identify.cumulative.FitSettings` ``soc_span``).

    ``log``: ``e``'s own run log, when ``e`` was cut from it at a profile step (:func:`plan_experiments`, its
    ``log_row``): the log's rows before that step (its rest before the profile) join the lead-in, so that the cell
    relaxes as long as it did. Left out, the model went from the preparation's last sample straight into the profile:
    on nca18650-true a 60 s rest after a C/2 discharge to SOC 0.2 and 30 min at rest, missing, left the truth itself
    0.47 mV RMS from its noise-free data on 3 A pulses down to 2.65 V (0.13 mV with it, the noise 0.1 mV)."""
    row = e.profile.params.get("log_row") if log is not None else None
    if log is not None and isinstance(row, int) and 0 < row < len(log):
        i_rest = 0.01 * float(cell["Q_nom"])
        if np.max(np.abs(log.current[:row])) <= i_rest:
            e = with_lead_in(e, log, 0, row, e.soc0)
    step2 = prep.columns[STEP_INDEX] == 2 if STEP_INDEX in prep.columns else np.zeros(len(prep), bool)
    first = np.flatnonzero(step2)
    where = prep.source or prep.name
    i_rest = 0.01 * float(cell["Q_nom"])
    if first.size == 0 or len(prep) < 3 or np.max(np.abs(prep.current[step2])) > i_rest:
        raise InputError(f"{where}: no rest after a full charge (plan step 2) to start the lead-in from")
    a, b = int(first[0]), len(prep) - 1
    full = any(k <= a and how.startswith(FULL_CHARGE) for k, _, how in state_steps(prep, cell, i_rest))
    passed = float(np.sum(prep.current[a:b] * np.diff(prep.t[a : b + 1]))) / 3600.0
    soc0 = full_soc if full else float(np.clip(e.soc0 - passed / cell.capacity(), 0.0, 1.0))
    return with_lead_in(e, prep, a, b, soc0)


def with_lead_in(e: Experiment, data: LoggedData, a: int, b: int, soc0: float, dt: float = LEAD_IN_DT) -> Experiment:
    """``e`` (whose profile starts at row ``b`` of ``data``) started at row ``a``: the logged current of rows [a, b)
    in charge-conserving bins of about ``dt`` [s] before ``e``'s samples, as its unscored lead-in (before any it
    has), from a uniform cell at ``soc0`` at the surface temperature logged at row ``a``."""
    t, i = data.t, data.current
    n = max(1, int(np.ceil((t[b] - t[a]) / dt - 1e-9)))
    grid = np.linspace(t[a], t[b], n + 1)
    charge = np.concatenate([[0.0], np.cumsum(i[a:b] * np.diff(t[a : b + 1]))])  # A s at rows a..b (ZOH)
    k = np.clip(np.searchsorted(t[a : b + 1], grid, side="right") - 1, 0, b - a)
    q = charge[k] + i[a:][np.minimum(k, b - a - 1)] * (grid - t[a : b + 1][k])
    q[-1] = charge[-1]
    p = e.profile
    prof = Profile(
        np.concatenate([grid[:-1] - t[a], p.t - p.t[0] + t[b] - t[a]]),
        np.concatenate([np.diff(q) / np.diff(grid), p.current]),
        id=p.id,
        kind=p.kind,
        soc0=soc0,
        params=dict(p.params),
    )
    q_var = np.broadcast_to(np.asarray(e.variance, float), e.voltage.shape)
    surf = data.temperature_K(SURFACE)
    T0 = float(surf[a]) if surf is not None and np.isfinite(surf[a]) else e.T0
    return replace(
        e,
        profile=prof,
        voltage=np.concatenate([np.interp(grid[:-1], t[a : b + 1], data.voltage[a : b + 1]), e.voltage]),
        soc0=soc0,
        variance=np.concatenate([np.full(n, q_var[0]), q_var]),
        T0=T0,
        mask=None if e.mask is None else np.concatenate([np.zeros(n, bool), e.mask]),
        truth=None if e.truth is None else np.concatenate([np.full(n, np.nan), e.truth]),
        temperature=None if e.temperature is None else np.concatenate([np.full(n, np.nan), e.temperature]),
        lead_in=n + e.lead_in,
    )


def repeated_trials(exps: Sequence[Experiment]) -> list[tuple[str, Any, np.ndarray]]:
    """The repeated trials among run-log experiments: (repeat key, the first trial's profile, voltages of shape
    (n_trials, n_samples) cut to the shortest trial) for every key with at least two trials. A trial split at a
    gap (several segments) is left out: its samples no longer line up with the others'."""
    by: dict[str, list[Experiment]] = {}
    split = {e.name.split("#")[0] for e in exps if "#" in e.name}
    for e in exps:
        key = e.profile.params.get("repeat_key")
        if key is not None and e.name not in split and "#" not in e.name:
            by.setdefault(str(key), []).append(e)
    out = []
    for key, trials in by.items():
        if len(trials) < 2:
            continue
        n = min(e.scored_voltage.size for e in trials)
        if n < 10:
            continue
        out.append((key, trials[0].scored_profile, np.stack([np.asarray(e.scored_voltage[:n], float) for e in trials])))
    return out


def logged_groups(loaded: Sequence[LoggedData]) -> list[DesignGroup] | None:
    """The design groups of the run logs that have a plan, merged (group k: the first log's parameters, the
    profiles every log's group k selected): each log's groups are those the runner stored with it (from the plan's
    design summary), else its plan's profile labels with the paper's Table 9 groups; None without a run log.
    Several logs are e.g. the groups of a sequential design, each run from its own plan."""
    merged: list[DesignGroup] = []
    found = False
    for d in loaded:
        groups: list[DesignGroup] | None = None
        stored = d.meta.get(DESIGN_GROUPS)
        if stored:
            try:
                groups = groups_from_dicts(stored)
            except (KeyError, TypeError):
                groups = None
        if groups is None:
            plan = logged_plan(d)
            if plan is None or not has_structure(d):
                continue
            groups = label_groups(plan.protocol)
        found = True
        for k, g in enumerate(groups):
            if k < len(merged):
                merged[k] = DesignGroup(merged[k].parameters, merged[k].selected | g.selected)
            else:
                merged.append(g)
    return merged if found else None


def experiments(
    data: LoggedData,
    cell: Cell,
    *,
    plan: Plan | None = None,
    plan_name: str = "the plan",
    **kwargs: Any,
) -> list[Experiment]:
    """The fit experiments of one logged test: cut at the profile steps of the run's plan when it is a run log (the
    logged plan, checked against ``plan`` when both are known), else one per segment between gaps
    (:func:`experiments_from_data`)."""
    if has_structure(data):
        logged = logged_plan(data)
        if logged is not None and plan is not None:
            check_same_plan(data, logged, plan, plan_name)
        use = logged or plan
        if use is not None:
            return plan_experiments(data, cell, use, **kwargs)
    return experiments_from_data(data, cell, **kwargs)


__all__ = [
    "DESIGN_GROUPS",
    "ProfileRun",
    "check_same_plan",
    "experiments",
    "has_structure",
    "logged_groups",
    "logged_plan",
    "plan_experiments",
    "profile_runs",
    "repeated_trials",
    "after_preparation",
    "with_lead_in",
]
