"""``battlab sensitivity``, ``battlab groups``, ``battlab design``: library sensitivities, parameter groups, and the
optimal selection of library profiles per group (issue 4)."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from protocols.errors import InputError


def _ids(text: str | None) -> list[int] | None:
    """``--ids 1,5,10-20`` → [1, 5, 10, …, 20]."""
    if not text:
        return None
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                out.extend(range(int(a), int(b) + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise InputError(f"--ids: expected ids like '1,5,10-20', got {part!r}") from None
    return out


@click.command("sensitivity")
@click.argument("library_path", metavar="LIBRARY.h5", type=click.Path(dir_okay=False))
@click.option("--cell", "cell_name", required=True, help="Built-in cell name or a BPX/TOML file.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Sensitivity store (.h5).")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: all cores).")
@click.option("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://HOST:8786 (instead of --workers).")
@click.option("--limit", type=int, default=None, help="Only the first N profiles (quick runs).")
@click.option("--ids", default=None, help="Only these profile ids, e.g. '1,5,10-20'.")
@click.option("--ambient", type=float, default=25.0, show_default=True, help="Ambient temperature [degC].")
@click.option(
    "--conventional/--no-conventional",
    default=True,
    show_default=True,
    help="Also simulate the conventional test set (the design's baseline).",
)
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
def sensitivity(
    library_path: str,
    cell_name: str,
    output: str,
    workers: int | None,
    scheduler: str | None,
    limit: int | None,
    ids: str | None,
    ambient: float,
    conventional: bool,
    progress: bool,
) -> None:
    """Simulate every profile of LIBRARY.h5 with all 18 voltage and temperature sensitivities into a store.

    Resumable: rerun the same command after an interruption and only the missing profiles are computed. A store
    made for another cell or model version is refused.
    """
    from rich.console import Console

    from battlab.cell import Cell
    from battlab.design import sweep
    from battlab.design.conventional import conventional_profiles
    from protocols.library import Library

    if workers is not None and scheduler is not None:
        raise InputError("give --workers or --scheduler, not both")
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if not -40.0 <= ambient <= 80.0:
        raise InputError(f"--ambient {ambient} degC is outside -40..80 degC")
    cell = Cell.load(cell_name)
    lib = Library.load(library_path)
    profs = sweep.select_profiles(lib, _ids(ids), limit)
    config = sweep.SweepConfig(ambient=ambient + 273.15)
    conv = conventional_profiles(float(cell["Q_nom"])) if conventional else []
    console = Console(stderr=True)
    rep = sweep.sweep(
        profs,
        cell,
        output,
        config=config,
        workers=workers,
        scheduler=scheduler,
        conventional=conv,
        library_path=library_path,
        progress=progress,
    )
    _print_sweep(console, rep)


def _print_sweep(console, rep) -> None:  # noqa: ANN001 (rich console, SweepReport)
    from rich.table import Table

    t = Table(title=f"sensitivity store {rep.path}")
    for col in ("profiles", "reused", "computed", "ok", "flagged", "failed", "wall / s", "cpu / s"):
        t.add_column(col, justify="right")
    t.add_row(
        *(str(v) for v in (rep.total, rep.reused, rep.computed, rep.ok, rep.flagged, rep.failed)),
        f"{rep.wall_seconds:.1f}",
        f"{rep.cpu_seconds:.1f}",
    )
    console.print(t)
    for pid, why in list(rep.failures.items())[:20]:
        console.print(f"[red]failed[/red] {pid}: {why}")
    if len(rep.failures) > 20:
        console.print(f"… and {len(rep.failures) - 20} more failures (see the store)")
    if rep.flagged:
        console.print(f"{rep.flagged} profiles flagged by the constraint screen (excluded from the design)")
    summary = {
        k: getattr(rep, k)
        for k in ("total", "reused", "computed", "ok", "flagged", "failed", "wall_seconds", "cpu_seconds")
    }
    summary["failures"] = {str(k): v for k, v in rep.failures.items()}
    summary["flagged_ids"] = sorted(str(k) for k in rep.flags)
    Path(rep.path).with_suffix(".summary.json").write_text(json.dumps(summary, indent=1))


def _open_store(path: str):  # noqa: ANN202 (SensitivityStore)
    from rich.console import Console

    from battlab.design.sweep import SensitivityStore

    store = SensitivityStore.open(path)
    if store.source_changed():
        Console(stderr=True).print(
            f"[yellow]note[/yellow]: the model's source changed since {path} was computed (same model version "
            f"{store.attrs['model_version']!r}); rerun `battlab sensitivity` to refresh stale profiles"
        )
    return store


def _load_groups(spec: str | None, ranking, k: int, by: str) -> tuple[list[list[str]], str]:  # noqa: ANN001
    """Groups from a JSON file, the paper's Table 9 ('paper'), or computed (None)."""
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
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    groups = data.get("groups") if isinstance(data, dict) else data
    if not isinstance(groups, list) or not all(isinstance(g, list) and g for g in groups):
        raise InputError(f"{path}: expected {{'groups': [[names…], …]}} or a list of lists of parameter names")
    return [[str(n) for n in g] for g in groups], str(path)


_NOISE_OPTION = click.option(
    "--unweighted", is_flag=True, help="Rank unweighted sensitivities (default: weighted by 1/q, eq. 40)."
)


@click.command("groups")
@click.argument("store_path", metavar="SENS.h5", type=click.Path(dir_okay=False))
@click.option("-k", "--n-groups", "k", type=int, default=4, show_default=True, help="Number of groups.")
@click.option(
    "--by",
    type=click.Choice(["mean", "stacked"]),
    default="mean",
    show_default=True,
    help="Group by the library-averaged magnitudes (paper, Fig. 4) or the stacked pivoted QR.",
)
@click.option(
    "-o",
    "--output",
    "out_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Directory for groups.json and the figures (default: beside the store).",
)
@click.option(
    "--perturb/--no-perturb",
    default=True,
    show_default=True,
    help="Draw the Fig. 5 perturbation plot (simulates one profile 3× per group).",
)
@click.option(
    "--profile",
    "profile_id",
    type=int,
    default=None,
    help="Profile for the perturbation plot (default: a drive cycle).",
)
@_NOISE_OPTION
def groups(
    store_path: str, k: int, by: str, out_dir: str | None, perturb: bool, profile_id: int | None, unweighted: bool
) -> None:
    """Rank the parameters by orthogonalised sensitivity, group them, and compare with the paper's Table 9."""
    from rich.console import Console
    from rich.table import Table

    from battlab import parameters
    from battlab.design import identifiability, information
    from battlab.plots import identifiability as figs

    console = Console()
    store = _open_store(store_path)
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
        table = Table(
            title=f"orthogonalised sensitivity ranking ({len(info)} profiles, "
            f"{'weighted by 1/q' if not unweighted else 'unweighted'}; {len(info.excluded)} excluded)"
        )
        for c in (
            "rank",
            "parameter",
            "symbol",
            "mean magnitude",
            "stacked QR",
            "group",
            "paper (Table 9)",
            "most collinear with",
        ):
            table.add_column(c, justify="right" if c in ("rank", "mean magnitude", "stacked QR") else "left")
        paper = {r["parameter"]: r["paper"] for r in identifiability.compare_with_paper(grp)}
        ours = {n: g + 1 for g, names in enumerate(grp) for n in names}
        for r, i in enumerate(ranking.order, start=1):
            n = info.names[i]
            partner, cosv = col.partner[n]
            table.add_row(
                str(r),
                n,
                parameters.SPECS[n].symbol,
                f"{ranking.mean[i]:.3e}",
                f"{ranking.stacked[i]:.3e}",
                str(ours[n]),
                str(paper.get(n, "-")),
                f"{partner} ({cosv:+.3f})",
            )
        console.print(table)
        ct = Table(title="collinearity index γ (Brun 2001; > 10-15: hard to identify together)")
        for c in ("group", "parameters", "γ group", "γ groups 1..k"):
            ct.add_column(c)
        for g, names in enumerate(grp):
            ct.add_row(str(g + 1), ", ".join(names), f"{col.groups[g]:.3g}", f"{col.cumulative[g]:.3g}")
        console.print(ct)
        fig4 = figs.ranking_bars(ranking, grp, out / f"{stem}.ranking.png")
        files = [str(fig4)]
        if perturb:
            files.append(
                str(_perturbation_plot(store, info, grp, ranking, profile_id, out / f"{stem}.perturbation.png"))
            )
        data = {
            "store": str(store_path),
            "cell": store.attrs["cell_name"],
            "by": by,
            "groups": grp,
            "paper_table9": [list(g) for g in identifiability.PAPER_TABLE9],
            "comparison": identifiability.compare_with_paper(grp),
            "ranking": ranking.to_dict(),
            "collinearity": col.to_dict(),
            "excluded": {str(k_): v for k_, v in info.excluded.items()},
            "figures": files,
        }
        gj = out / f"{stem}.groups.json"
        gj.write_text(json.dumps(data, indent=1, default=float))
        console.print(f"wrote {gj} and {', '.join(files)}")


def _perturbation_plot(store, info, grp, ranking, profile_id, path: Path) -> Path:  # noqa: ANN001
    """Fig. 5: the top parameter of each group set to θ̄ ∈ {0, 0.5, 1} on one profile (each value is a new cell:
    the model is rebuilt for it, about 2 s)."""
    from battlab.plots import identifiability as figs
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


@click.command("design")
@click.argument("store_path", metavar="SENS.h5", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Plan TOML to write.")
@click.option(
    "--criterion",
    type=click.Choice(["D", "A", "E"], case_sensitive=False),
    default="D",
    show_default=True,
    help="Optimality criterion.",
)
@click.option("-M", "M", type=int, default=5, show_default=True, help="Profiles per group.")
@click.option("--budget", type=float, default=None, help="Budget per group on --cost (eq. 35), e.g. seconds.")
@click.option(
    "--cost",
    type=click.Choice(["duration", "throughput"]),
    default="duration",
    show_default=True,
    help="Per-profile cost for --budget: duration [s] or charge throughput [Ah].",
)
@click.option(
    "--costs",
    "costs_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="JSON {profile id: cost} of user-given costs for --budget.",
)
@click.option("-k", "--n-groups", "k", type=int, default=4, show_default=True, help="Number of groups.")
@click.option(
    "--groups",
    "groups_spec",
    default=None,
    help="Groups: a JSON file from `battlab groups`, or 'paper' for Table 9 (default: computed).",
)
@click.option(
    "--cumulative/--separate",
    default=True,
    show_default=True,
    help="Group k's design uses the parameters of groups 1..k (the paper) or of group k only.",
)
@click.option("--exact", is_flag=True, help="Also run the exact branch and bound (D and A, no budget).")
@click.option("--include-flagged", is_flag=True, help="Let profiles flagged by the constraint screen be chosen.")
@click.option(
    "--solver",
    type=click.Choice(["CLARABEL", "SCS"], case_sensitive=False),
    default=None,
    help="Convex solver (default: Clarabel, SCS if it fails).",
)
@click.option(
    "--singular",
    type=click.Choice(["project", "error"]),
    default="project",
    show_default=True,
    help="When no profile resolves some parameter direction: design on the identifiable subspace and report the "
    "directions, or stop with an error naming them.",
)
@_NOISE_OPTION
def design(
    store_path: str,
    output: str,
    criterion: str,
    M: int,
    budget: float | None,
    cost: str,
    costs_file: str | None,
    k: int,
    groups_spec: str | None,
    cumulative: bool,
    exact: bool,
    include_flagged: bool,
    solver: str | None,
    singular: str,
    unweighted: bool,
) -> None:
    """Select M library profiles per parameter group (convex relaxation, rounding, checks) and write the plan.

    Writes the plan TOML (whole experiment), one TOML per group, summary.json and <plan>.design.json beside it,
    and a figure of the relaxed weights.
    """
    import time

    from rich.console import Console

    from battlab.design import groups as gd
    from battlab.design import identifiability, information
    from battlab.design import plan as planmod
    from battlab.design.criteria import Criterion
    from battlab.noise import NoiseModel
    from battlab.plots import identifiability as figs

    if M < 1:
        raise InputError(f"-M must be at least 1, got {M}")
    if budget is not None and budget <= 0:
        raise InputError(f"--budget must be positive, got {budget}")
    costs = None
    if costs_file:
        try:
            raw = json.loads(Path(costs_file).read_text())
            costs = {str(k_): float(v) for k_, v in raw.items()}
        except (OSError, json.JSONDecodeError, AttributeError, TypeError, ValueError) as exc:
            raise InputError(f"{costs_file}: expected a JSON object {{profile id: cost}} ({exc})") from None
    console = Console()
    store = _open_store(store_path)
    with store:
        t0 = time.perf_counter()
        info = information.load(store, include_flagged=include_flagged)
        if unweighted:
            info = information.Information(info.ids, info.names, info.R, np.ones(len(info)), info.meta, info.excluded)
        conv = information.conventional(store, None if not unweighted else NoiseModel(floor=1.0))
        ranking = identifiability.rank(info.W, info.names, info.ids)
        grp, source = _load_groups(groups_spec, ranking, k, "mean")
        settings = gd.Settings(
            M=M,
            criterion=Criterion.of(criterion),
            budget=budget,
            cost=cost,
            costs=costs,
            cumulative=cumulative,
            exact=exact,
            solver=solver,
            on_singular=singular,
        )
        designs = gd.design_groups(info, grp, settings, conv)
        solve_seconds = time.perf_counter() - t0
        meta_by_id = {m["id"]: m for m in info.meta}
        files = planmod.write_plan(
            designs,
            store,
            output,
            criterion=settings.criterion.value,
            solve_seconds=solve_seconds,
            extra={
                "groups_source": source,
                "M": M,
                "budget": budget,
                "cost": cost,
                "cumulative": cumulative,
                "n_candidates": len(info),
                "excluded": {str(k_): v for k_, v in info.excluded.items()},
                "selected_profiles": {str(pid): meta_by_id[pid] for d in designs for pid in d.selected},
            },
        )
        fig = figs.design_weights(designs, Path(output).with_suffix(".weights.png"))
    _print_design(console, designs, meta_by_id, settings, source, len(info), solve_seconds)
    console.print(f"wrote {files.plan}, {', '.join(str(p) for p in files.groups)}, {files.summary}, {fig}")


def _print_design(console, designs, meta, settings, source, n, seconds) -> None:  # noqa: ANN001
    from rich.table import Table

    c = settings.criterion.value
    t = Table(title=f"{c}-optimal design, M = {settings.M}, {n} candidates, groups {source}, {seconds:.2f} s")
    for col in ("group", "new parameters", "selected", "log det F", "gap", "integral", "check", "random", "vs conv."):
        t.add_column(col)
    for d in designs:
        fo = d.first_order
        check = "ok" if fo.get("agree") else "DISAGREE"
        if fo.get("d_efficiency") is not None:
            check += f" {abs(fo['d_efficiency'] - 1):.0e}"
        if d.exact is not None:
            check += "; exact" if d.exact["optimal"] else "; not proved"
        conv = d.conventional
        t.add_row(
            str(d.index),
            ", ".join(d.new_parameters),
            ", ".join(str(p) for p in d.selected),
            f"{d.logdet:.2f}",
            f"{d.relaxation_gap:.2g}",
            "yes" if d.integrality.integral else f"no ({d.integrality.fractional})",
            check,
            f"{d.random.get('median', float('nan')):.2f}/{d.random.get('max', float('nan')):.2f}",
            "n/a" if conv is None else f"{conv['efficiency']:.3g}×",
        )
    console.print(t)
    from battlab.identify.symmetry import complete_electrodes

    for d in designs:
        for nd in d.unidentifiable:
            console.print(
                f"[yellow]group {d.index}: not identifiable from any library profile[/yellow]: "
                f"{nd.describe()}; designed on the identifiable subspace"
            )
        if d.unidentifiable and complete_electrodes(d.parameters):
            console.print(
                f"group {d.index}: R_s, D_s, k, R_f of electrode(s) {', '.join(complete_electrodes(d.parameters))} "
                "are moved together by the model's exact scaling symmetry (battlab.identify.symmetry): no experiment "
                "separates them; fix one of the four to identify the others"
            )
    console.print(
        "gap: relaxed optimum − rounded design (log det for D); integral: relaxed η ∈ {0, 1/M}; check: agreement "
        "with the independent algorithm (|D-eff − 1|); random: median/max efficiency of random designs relative to "
        "this one; vs conv.: efficiency relative to the conventional test set"
    )
    chosen: dict = {}
    for d in designs:
        for pid in d.selected:
            chosen.setdefault(pid, []).append(str(d.index))
    pt = Table(title="selected profiles")
    for col in ("id", "groups", "profile", "start SOC", "duration / s", "T_surface max / degC"):
        pt.add_column(col)
    for pid, gs in chosen.items():
        m = meta[pid]
        pt.add_row(
            str(pid),
            ",".join(gs),
            str(m.get("params", {}).get("name", m["kind"])),
            f"{m['soc0']:g}",
            f"{m['duration']:.0f}",
            f"{m['T_surface_max_C']:.1f}",
        )
    console.print(pt)
