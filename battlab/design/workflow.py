"""The design steps as functions on values: the library sweep, the parameter groups, the optimal selection.

Each takes what a user has (a library, a cell, a sensitivity store) and returns a report value; results are
written where the step's product belongs (the store, ``groups.json`` and figures, the plan). Nothing is printed:
progress goes to ``subscribers`` (:mod:`battlab.progress`), and the command line renders the reports.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.progress import Subscriber
from protocols.errors import InputError


def sweep(
    library: str | Path,
    cell: Cell | str,
    output: str | Path,
    *,
    ids: Sequence[int] | None = None,
    limit: int | None = None,
    ambient_C: float = 25.0,
    conventional: bool = True,
    workers: int | None = None,
    scheduler: str | None = None,
    subscribers: Sequence[Subscriber] = (),
) -> Any:  # SweepReport
    """Every profile of the library (or ``ids``/the first ``limit``) simulated with all 18 sensitivities into the
    store ``output`` (resumable); with ``conventional`` also the conventional test set, the design's baseline."""
    from battlab.design import sweep as sw
    from battlab.design.conventional import conventional_profiles
    from protocols.library import Library

    if workers is not None and scheduler is not None:
        raise InputError("give workers or a scheduler, not both")
    if workers is not None and workers < 1:
        raise InputError(f"workers must be at least 1, got {workers}")
    if not -40.0 <= ambient_C <= 80.0:
        raise InputError(f"ambient {ambient_C} degC is outside -40..80 degC")
    cell = cell if isinstance(cell, Cell) else Cell.load(cell)
    lib = Library.load(library)
    profs = sw.select_profiles(lib, list(ids) if ids else None, limit)
    conv = conventional_profiles(float(cell["Q_nom"])) if conventional else []
    return sw.sweep(
        profs,
        cell,
        output,
        config=sw.SweepConfig(ambient=ambient_C + 273.15),
        workers=workers,
        scheduler=scheduler,
        conventional=conv,
        library_path=str(library),
        progress=False,
        subscribers=subscribers,
    )


def sweep_summary(rep: Any) -> dict[str, Any]:
    """The machine-readable summary of a sweep report."""
    keys = ("total", "reused", "computed", "ok", "flagged", "failed", "wall_seconds", "cpu_seconds")
    out: dict[str, Any] = {k: getattr(rep, k) for k in keys}
    out["failures"] = {str(k): v for k, v in rep.failures.items()}
    out["flagged_ids"] = sorted(str(k) for k in rep.flags)
    return out


def open_store(path: str | Path) -> tuple[Any, str | None]:
    """The store and, when the model's source changed since it was computed, a note saying so."""
    from battlab.design.sweep import SensitivityStore

    store = SensitivityStore.open(path)
    note = None
    if store.source_changed():
        note = (
            f"the model's source changed since {path} was computed (same model version "
            f"{store.attrs['model_version']!r}); rerun `battlab sensitivity` to refresh stale profiles"
        )
    return store, note


def load_groups(spec: str | None, ranking: Any, k: int, by: str) -> tuple[list[list[str]], str]:
    """Groups from a JSON file, the paper's Table 9 (``"paper"``), or computed (None)."""
    from battlab.design import identifiability

    if spec is None:
        return identifiability.group(ranking, k, by=by), f"computed (natural breaks, k = {k}, by {by})"
    if spec == "paper":
        return [list(g) for g in identifiability.PAPER_TABLE9], "the paper's Table 9"
    path = Path(spec)
    if not path.is_file():
        raise InputError(f"--groups {spec}: no such file (give a groups JSON, or 'paper')")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    groups = data.get("groups") if isinstance(data, dict) else data
    if not isinstance(groups, list) or not all(isinstance(g, list) and g for g in groups):
        raise InputError(f"{path}: expected {{'groups': [[names…], …]}} or a list of lists of parameter names")
    return [[str(n) for n in g] for g in groups], str(path)


@dataclass(frozen=True)
class GroupsReport:
    """Ranking, groups and collinearity of a store's profiles, and the files written."""

    info: Any  # information.Information
    ranking: Any  # identifiability.Ranking
    groups: list[list[str]]
    collinearity: Any  # identifiability.Collinearity
    paper: Mapping[str, Any]  # parameter -> its Table 9 group
    weighted: bool
    data: Mapping[str, Any]  # groups.json
    path: Path  # groups.json
    figures: list[str]
    note: str | None = None


def groups(
    store_path: str | Path,
    *,
    k: int = 4,
    by: str = "mean",
    out_dir: str | Path | None = None,
    perturb: bool = True,
    profile_id: int | None = None,
    unweighted: bool = False,
) -> GroupsReport:
    """Rank the parameters by orthogonalised sensitivity (Fig. 4), group them (Table 9), write ``groups.json``
    and the figures (Fig. 4 and, with ``perturb``, Fig. 5)."""
    from battlab.design import figures as figs
    from battlab.design import identifiability, information

    store, note = open_store(store_path)
    with store:
        info = information.load(store)
        W = info.R if unweighted else info.W
        ranking = identifiability.rank(W, info.names, info.ids, weighted=not unweighted)
        if not 1 <= k <= len(info.names):
            raise InputError(f"-k must be between 1 and {len(info.names)}, got {k}")
        grp = identifiability.group(ranking, k, by=by)
        G = np.einsum("lki,lkj->ij", W, W)
        col = identifiability.collinearity(G, info.names, grp)
        out = Path(out_dir) if out_dir else Path(store_path).resolve().parent
        out.mkdir(parents=True, exist_ok=True)
        stem = Path(store_path).stem
        comparison = identifiability.compare_with_paper(grp)
        files = [str(figs.ranking_bars(ranking, grp, out / f"{stem}.ranking.png"))]
        if perturb:
            files.append(
                str(perturbation_plot(store, info, grp, ranking, profile_id, out / f"{stem}.perturbation.png"))
            )
        data = {
            "store": str(store_path),
            "cell": store.attrs["cell_name"],
            "by": by,
            "groups": grp,
            "paper_table9": [list(g) for g in identifiability.PAPER_TABLE9],
            "comparison": comparison,
            "ranking": ranking.to_dict(),
            "collinearity": col.to_dict(),
            "excluded": {str(k_): v for k_, v in info.excluded.items()},
            "figures": files,
        }
        gj = out / f"{stem}.groups.json"
        gj.write_text(json.dumps(data, indent=1, default=float))
    paper = {r["parameter"]: r["paper"] for r in comparison}
    return GroupsReport(info, ranking, grp, col, paper, not unweighted, data, gj, files, note)


def perturbation_plot(store: Any, info: Any, grp: Any, ranking: Any, profile_id: int | None, path: Path) -> Path:
    """Fig. 5: the top parameter of each group set to θ̄ ∈ {0, 0.5, 1} on one profile (each value is a new cell:
    the model is rebuilt for it, about 2 s)."""
    from battlab.design import figures as figs
    from battlab.simulation import simulate

    cell = store.cell()
    if profile_id is None:
        drives = [m["id"] for m in info.meta if m["kind"] == "drive"]
        profile_id = drives[len(drives) // 2] if drives else info.ids[0]
    prof = store.profile(profile_id)
    runs = []
    for g, names in enumerate(grp, start=1):
        rep = max(names, key=lambda n: ranking.mean[info.names.index(n)])
        curves = []
        for tb in (0.0, 0.5, 1.0):
            res = simulate(cell.with_normalised(**{rep: tb}), prof)
            curves.append((tb, res.t, res.voltage))
        runs.append({"parameter": rep, "group": g, "curves": curves})
    name = prof.params.get("name", "") if prof.params else ""
    return figs.perturbation(runs, path, f"profile {profile_id} {name} (start SOC {prof.soc0})")


def window_screen(store: Any, info: Any, cell: Cell, limits: Any = None) -> Any:
    """The candidates whose run on the design cell keeps the plan's window (:mod:`battlab.lab.window`): the
    coulomb-counted SOC within [SOC_MARGIN, 1 − SOC_MARGIN] from the profile's start SOC (the cell's capacity) and
    the voltage the sweep simulated at least VOLTAGE_MARGIN_V inside ``limits`` (default: the plan's
    :class:`protocols.protocol.SafetyLimits`). The others move to ``info.excluded`` with the reason."""
    from battlab.design.sweep.store import GROUP, group_name
    from battlab.lab.window import SOC_MARGIN, VOLTAGE_MARGIN_V
    from protocols.protocol import SafetyLimits

    lim = limits or SafetyLimits()
    lo, hi = lim.voltage_min + VOLTAGE_MARGIN_V, lim.voltage_max - VOLTAGE_MARGIN_V
    cap = cell.capacity()
    keep, excluded = [], dict(info.excluded)
    for k, pid in enumerate(info.ids):
        prof = store.profile(pid)
        soc = prof.soc(cap, float(prof.soc0))
        v = store.f[GROUP][group_name(pid)]["voltage"][()]
        if soc.min() < SOC_MARGIN or soc.max() > 1 - SOC_MARGIN:
            excluded[pid] = (
                f"window: from SOC {prof.soc0:g} it passes SOC {soc.min():.3f}–{soc.max():.3f}, outside "
                f"[{SOC_MARGIN:g}, {1 - SOC_MARGIN:g}]"
            )
        elif v.min() < lo or v.max() > hi:
            excluded[pid] = (
                f"window: its voltage spans {v.min():.3f}–{v.max():.3f} V, within {VOLTAGE_MARGIN_V:g} V of the "
                f"plan's limits [{lim.voltage_min:g}, {lim.voltage_max:g}] V"
            )
        else:
            keep.append(k)
    if not keep:
        raise InputError(f"{store.path}: no profile keeps the plan's SOC and voltage window ({len(excluded)} excluded)")
    return _subset(info, keep, excluded)


def _subset(info: Any, keep: Sequence[int], excluded: Mapping[Any, str]) -> Any:
    from battlab.design.information import Information

    return Information(
        tuple(info.ids[k] for k in keep),
        info.names,
        info.R[list(keep)],
        info.q[list(keep)],
        tuple(info.meta[k] for k in keep) if info.meta else (),
        dict(excluded),
    )


@dataclass(frozen=True)
class DesignReport:
    """The designs per group and what was written."""

    designs: list[Any]  # groups.GroupDesign
    meta: Mapping[Any, Mapping[str, Any]]  # profile id -> its metadata
    settings: Any  # groups.Settings
    source: str  # where the groups came from
    n_candidates: int
    solve_seconds: float
    files: Any  # plan.PlanFiles
    figure: Path
    note: str | None = None
    #: the written plan's window check on the design cell (battlab.lab.window.WindowReport)
    window: Any = None
    #: candidates left out because they leave the plan's SOC or voltage window: id -> reason
    window_excluded: Mapping[Any, str] = field(default_factory=dict)
    #: per selected profile, the candidates that best take its place if it cannot be run, best first
    #: (:func:`battlab.design.replacement.replacements`)
    replacements: Mapping[Any, list[Any]] = field(default_factory=dict)


#: designs tried when the written plan fails its window check (each retry leaves out the profiles that failed)
WINDOW_ATTEMPTS = 3


def _check_arguments(
    M: int, budget: float | None, noise_trials: int, noise_per_direction: int, rest_before_s: float
) -> None:
    """One :class:`InputError` for the first design argument out of its range."""
    if M < 1:
        raise InputError(f"-M must be at least 1, got {M}")
    if not rest_before_s >= 1800.0:
        raise InputError(f"--rest-before must be at least 1800 s (the fit's start state needs it), got {rest_before_s}")
    if noise_trials == 1 or noise_trials < 0:
        raise InputError(f"--noise-trials must be 0 (none) or at least 2 (eq. 36 needs repeats), got {noise_trials}")
    if noise_trials and noise_per_direction < 1:
        raise InputError(f"--noise-profiles must be at least 1, got {noise_per_direction}")
    if budget is not None and budget <= 0:
        raise InputError(f"--budget must be positive, got {budget}")


def _information(
    store: Any,
    noise: Any,
    include_flagged: bool,
    unweighted: bool,
    groups: Sequence[Sequence[str]] | None,
    groups_spec: str | None,
    k: int,
) -> tuple[Any, Any, list[list[str]], str]:
    """The candidates' information (eqs. 26–27, weighted by ``noise`` unless ``unweighted``), the conventional
    tests' information, the parameter groups and where they came from (``"given"`` or the groups' source)."""
    from battlab.design import identifiability, information
    from battlab.noise import NoiseModel

    info = information.load(store, noise, include_flagged=include_flagged)
    if unweighted:
        info = information.Information(info.ids, info.names, info.R, np.ones(len(info)), info.meta, info.excluded)
    conv = information.conventional(store, noise if not unweighted else NoiseModel(floor=1.0))
    if groups is not None:
        return info, conv, [list(g) for g in groups], "given"
    ranking = identifiability.rank(info.W, info.names, info.ids)
    grp, source = load_groups(groups_spec, ranking, k, "mean")
    return info, conv, grp, source


def _add_spares(store: Any, info: Any, designs: Sequence[Any], settings: Any, files: Any, window: Any) -> Any:
    """The spares of each selected profile (:func:`battlab.design.replacement.replacements`) and the simulated
    voltage spans of every profile listed, added to the plan's summary with its window check; the spares."""
    from battlab.design import plan as planmod
    from battlab.design import replacement

    spares = replacement.replacements(info, designs, settings.criterion)
    listed = {pid for d in designs for pid in d.selected} | {c for v in spares.values() for c in v}
    spans = replacement.voltage_spans(store, sorted(listed, key=str))
    planmod.add_to_summary(
        files,
        window=window.to_dict(),
        replacements=replacement.as_json(spares),
        voltage_span={str(k_): list(v) for k_, v in spans.items()},
    )
    return spares


def _design_in_window(
    info: Any, grp: Sequence[Sequence[str]], settings: Any, conv: Any, cell: Any, write: Callable[..., Any]
) -> tuple[Any, Any, Any, Any]:
    """Design the groups and write the plan (``write(designs, info)``) until its window check passes, leaving out
    the profiles that failed it each time (at most :data:`WINDOW_ATTEMPTS` designs); (designs, the information
    left, the plan's files, its window check)."""
    from battlab.design import groups as gd

    for attempt in range(1, WINDOW_ATTEMPTS + 1):
        designs = gd.design_groups(info, grp, settings, conv)
        files = write(designs, info)
        window = _check_plan_window(files.plan, cell)
        failed = {p.profile_id: f"window: {p.problem}" for p in window.profiles if p.problem}
        if not failed:
            break
        if attempt == WINDOW_ATTEMPTS:
            window.raise_if_bad(str(files.plan))
        keep = [k for k, pid in enumerate(info.ids) if pid not in failed]
        info = _subset(info, keep, {**info.excluded, **failed})
    return designs, info, files, window


def design(
    store_path: str | Path,
    output: str | Path,
    *,
    criterion: str = "D",
    M: int = 5,
    budget: float | None = None,
    cost: str = "duration",
    costs: Mapping[str, float] | None = None,
    k: int = 4,
    groups_spec: str | None = None,
    cumulative: bool = True,
    exact: bool = False,
    include_flagged: bool = False,
    solver: str | None = None,
    singular: str = "project",
    unweighted: bool = False,
    noise: Any = None,
    groups: Sequence[Sequence[str]] | None = None,
    noise_trials: int = 0,
    noise_per_direction: int = 2,
    rest_before_s: float = 1800.0,
) -> DesignReport:
    """Select ``M`` library profiles per parameter group (convex relaxation, rounding, checks; eqs. 26–35) and
    write the plan TOML (whole experiment), one TOML per group, ``<plan>.summary.json`` and a figure of the
    weights. ``noise`` (a :class:`battlab.noise.NoiseModel`, eqs. 36–40): the model that weights the information
    (default: the paper's); ``groups``: the parameter groups themselves (instead of ``groups_spec``).
    ``noise_trials`` ≥ 2: the plan starts with that many repeated trials of ``noise_per_direction`` charge-only and
    as many discharge-only pulse profiles of the store's library (:func:`noise_trial_profiles`), from which
    ``battlab fit`` fits eq. 38 (:mod:`battlab.identify.weights`); the summary's ``noise_trials`` lists them.
    ``rest_before_s``: the rest before every profile [s] (:data:`battlab.design.plan.REST_BEFORE_S`)."""
    from battlab.design import figures as figs
    from battlab.design import groups as gd
    from battlab.design import plan as planmod
    from battlab.design.criteria import Criterion

    _check_arguments(M, budget, noise_trials, noise_per_direction, rest_before_s)
    store, note = open_store(store_path)
    with store:
        t0 = time.perf_counter()
        info, conv, grp, source = _information(store, noise, include_flagged, unweighted, groups, groups_spec, k)
        settings = gd.Settings(
            M=M,
            criterion=Criterion.of(criterion),
            budget=budget,
            cost=cost,
            costs=dict(costs) if costs is not None else None,
            cumulative=cumulative,
            exact=exact,
            solver=solver,
            on_singular=singular,
        )
        cell = store.cell()
        noise_profs = noise_trial_profiles(store, cell, noise_per_direction) if noise_trials else []
        before = set(info.excluded)
        info = window_screen(store, info, cell)
        trials = {"trials": noise_trials, "profiles": [str(p.id) for p in noise_profs]} if noise_trials else None
        extra = {"groups_source": source, "M": M, "budget": budget, "cost": cost, "cumulative": cumulative}

        def write(designs: Sequence[Any], info: Any) -> Any:
            meta = {m["id"]: m for m in info.meta}
            return planmod.write_plan(
                designs,
                store,
                output,
                criterion=settings.criterion.value,
                solve_seconds=time.perf_counter() - t0,
                ocv_table=planmod.ocv_table(cell),
                extra={
                    **extra,
                    "noise_trials": trials,
                    "n_candidates": len(info),
                    "excluded": {str(k_): v for k_, v in info.excluded.items()},
                    "selected_profiles": {str(pid): meta[pid] for d in designs for pid in d.selected},
                },
                noise=noise_profs,
                trials=noise_trials,
                rest_before_s=rest_before_s,
            )

        designs, info, files, window = _design_in_window(info, grp, settings, conv, cell, write)
        solve_seconds = time.perf_counter() - t0
        spares = _add_spares(store, info, designs, settings, files, window)
        fig = figs.design_weights(designs, Path(output).with_suffix(".weights.png"))
    excluded = {k_: v for k_, v in info.excluded.items() if k_ not in before}
    meta, n = {m["id"]: m for m in info.meta}, len(info)
    return DesignReport(designs, meta, settings, source, n, solve_seconds, files, fig, note, window, excluded, spares)


#: [s] the longest noise-trial profile (the campaign's quick setting): repeats multiply its cost
NOISE_MAX_S = 900.0


def noise_trial_profiles(store: Any, cell: Cell, per_direction: int) -> list[Any]:
    """Pulse profiles for repeated noise trials from the library the store was swept from: ``per_direction``
    charge-only and as many discharge-only ones spread over the intensities (eq. 38 fits one curve per direction),
    gentle enough to stay inside the window on the design cell (the campaign's choice,
    :func:`battlab.design.noise_trials.noise_profiles`), at most :data:`NOISE_MAX_S` long."""
    from battlab.design.noise_trials import noise_profiles
    from protocols.library import Library

    lib_path = store.attrs.get("library_path") or ""
    if not lib_path or not Path(lib_path).is_file():
        raise InputError(
            f"{store.path}: --noise-trials picks its profiles from the library the store was swept from, and "
            f"{lib_path or 'none'} is not there"
        )
    picks = noise_profiles(Library.load(lib_path), per_direction, cell, NOISE_MAX_S)
    if not picks:
        raise InputError(f"{lib_path}: no charge-only or discharge-only pulse profile fits the noise trials")
    return picks


def _check_plan_window(plan: Path, cell: Cell) -> Any:
    """The written plan's window on the design cell, from its first step (a full charge)."""
    from battlab.io.plan import Plan
    from battlab.lab.window import check_window

    loaded = Plan.load(plan)
    return check_window(loaded.protocol, cell, ambient_K=loaded.options.ambient_degC + 273.15)
