"""How a fit is laid out before it runs: the stages of the cumulative fit (from a plan's design groups, a run
log's, or named parameters), unique experiment names, and the full-charge window of an OCV test's start."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from battlab.cell import Cell
from protocols.errors import InputError


def full_charge_at_ocv_start(eq: Any) -> Cell:
    """The equilibrium fit's cell with SOC 1 moved to the state at the start of its OCV test (θ⁻ at q = 0, θ⁺ from
    the lithium balance, eq. 10); SOC 0 stays where the OCV reaches V_min. A test that starts right after the lab's
    full charge (a CCCV to V_max with a small cut-off current, then a rest) starts below V_max on the OCV; with
    this window ``soc0=1`` is the cell as that charge leaves it."""
    n0, _, p0, _ = eq.cell.stoichiometry_window()
    tn = float(eq.theta_n0)
    tp = (float(eq.n_Li) - float(eq.H_n) * tn) / float(eq.H_p)
    if not (n0 < tn < 1.0 and 0.0 < tp < p0):
        raise InputError(
            f"the OCV test's start (θ⁻ {tn:.4f}, θ⁺ {tp:.4f}) is not inside the cell's window from V_min "
            f"(θ⁻ {n0:.4f}, θ⁺ {p0:.4f}): it cannot be the full charge"
        )
    src = f"the state at the start of the OCV test {eq.curve.source}".strip()
    values = {"sto_n_0": n0, "sto_n_100": tn, "sto_p_0": p0, "sto_p_100": tp}
    new = eq.cell.with_values(**values)
    return Cell(new.name, new.values, {**new.sources, **{k: src for k in values}}, new.description)


def plan_groups(plan: Path) -> list[tuple[list[str], set[str]]]:
    """Groups (parameters, selected profile ids) of a design plan (:func:`battlab.io.plan.design_groups`)."""
    from battlab.io.plan import design_groups

    return [(list(g.parameters), set(g.selected)) for g in design_groups(plan)]


def _home_stages(experiments: list[Any], groups: list[tuple[Sequence[str], set[str]]]) -> dict[int, int]:
    """Each experiment's group (0-based): that of its run log step's ``group`` when that group selected its
    profile's ``library_id``, else the first group that selected it, else the first."""

    def lib_id(e: Any) -> str:
        return str(e.profile.params.get("library_id", e.name))

    home: dict[int, int] = {}
    for i, e in enumerate(experiments):
        k = e.profile.params.get("group")
        if isinstance(k, int) and 1 <= k <= len(groups) and lib_id(e) in groups[k - 1][1]:
            home[i] = k - 1
    for i, e in enumerate(experiments):
        if i not in home:
            home[i] = next((k for k, (_, sel) in enumerate(groups) if lib_id(e) in sel), 0)
    return home


def stages(
    params: str | None,
    plan: str | Path | None,
    experiments: list[Any],
    groups: Sequence[tuple[Sequence[str], set[str]]] | None = None,
    cell: Cell | None = None,
) -> list[Any]:
    """Stages of the cumulative fit: from the plan's design summary, else the given ``groups`` (parameters,
    selected library ids; e.g. a run log's), else ``params`` (table9 | all | NAMES; None: table9). Each experiment
    joins one stage (:func:`_home_stages`; the fit is cumulative: later stages see it too). With model extensions
    on in ``cell``, their parameters join the last stage (``all``: every parameter of ``cell``)."""
    from battlab import parameters
    from battlab.identify.fit import Stage

    extra = cell.parameter_names()[len(parameters.NAMES) :] if cell is not None else ()
    if plan is not None:
        groups = plan_groups(Path(plan))
    if groups is not None:
        groups = [(list(n), set(s)) for n, s in groups]
        home = _home_stages(experiments, groups)
        out = [
            Stage(tuple(names), tuple(e for i, e in enumerate(experiments) if home[i] == k))
            for k, (names, _) in enumerate(groups)
        ]
        if out and extra:
            out[-1] = Stage(out[-1].names + tuple(extra), out[-1].experiments)
        return out
    p = (params or "table9").strip()
    if p == "none":
        return []
    if p == "table9":
        table9 = list(parameters.TABLE9_GROUPS)
        table9[-1] = table9[-1] + tuple(extra)
        return [Stage(g, tuple(experiments) if k == 0 else ()) for k, g in enumerate(table9)]
    names = [*parameters.NAMES, *extra] if p == "all" else [s.strip() for s in p.split(",") if s.strip()]
    return [Stage(parameters.check_names(names), tuple(experiments))]


def unique_names(experiments: list[Any]) -> list[Any]:
    """The experiments with unique names: a name met again (data files of the same name from different
    directories, e.g. the run logs of a sequential design) gets ``~2``, ``~3``, … in the order given (the summary's
    RMSE and the stages' experiment lists are keyed by name)."""
    seen: dict[str, int] = {}
    out = []
    for e in experiments:
        n = seen.get(e.name, 0) + 1
        seen[e.name] = n
        out.append(e if n == 1 else replace(e, name=f"{e.name}~{n}"))
    return out
