"""``battlab sensitivity``, ``battlab groups``, ``battlab design``: thin shells over :mod:`battlab.design.workflow`
(library sensitivities, parameter groups, the optimal selection of library profiles per group)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from battlab.cli.console import make_console
from battlab.cli.options import ambient_option
from battlab.io.paths import check_output_path, summary_path
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
@ambient_option()
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
    from battlab.design import workflow
    from battlab.progress import RichBar

    check_output_path(output, create=True)
    rep = workflow.sweep(
        library_path,
        cell_name,
        output,
        ids=_ids(ids),
        limit=limit,
        ambient_C=ambient,
        conventional=conventional,
        workers=workers,
        scheduler=scheduler,
        subscribers=[RichBar()] if progress else [],
    )
    _print_sweep(make_console(stderr=True), rep)


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
    from battlab.design.workflow import sweep_summary

    summary_path(rep.path).write_text(json.dumps(sweep_summary(rep), indent=1))


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
    from rich.table import Table

    from battlab import parameters
    from battlab.design import workflow

    if out_dir is not None:
        check_output_path(out_dir, directory=True, create=True)
    console = make_console()
    rep = workflow.groups(
        store_path, k=k, by=by, out_dir=out_dir, perturb=perturb, profile_id=profile_id, unweighted=unweighted
    )
    _note(rep.note)
    info, ranking, col = rep.info, rep.ranking, rep.collinearity
    table = Table(
        title=f"orthogonalised sensitivity ranking ({len(info)} profiles, "
        f"{'weighted by 1/q' if rep.weighted else 'unweighted'}; {len(info.excluded)} excluded)"
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
    ours = {n: g + 1 for g, names in enumerate(rep.groups) for n in names}
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
            str(rep.paper.get(n, "-")),
            f"{partner} ({cosv:+.3f})",
        )
    console.print(table)
    ct = Table(title="collinearity index γ (Brun 2001; > 10-15: hard to identify together)")
    for c in ("group", "parameters", "γ group", "γ groups 1..k"):
        ct.add_column(c)
    for g, names in enumerate(rep.groups):
        ct.add_row(str(g + 1), ", ".join(names), f"{col.groups[g]:.3g}", f"{col.cumulative[g]:.3g}")
    console.print(ct)
    console.print(f"wrote {rep.path} and {', '.join(rep.figures)}")


def _note(note: str | None) -> None:
    if note:
        make_console(stderr=True).print(f"[yellow]note[/yellow]: {note}")


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
@click.option(
    "--noise-trials",
    type=int,
    default=0,
    show_default=True,
    help="Start the plan with this many repeated trials (>= 2) of noise profiles, from which `battlab fit` fits "
    "the noise model (eqs. 36-38); 0: none.",
)
@click.option(
    "--noise-profiles",
    "noise_per_direction",
    type=int,
    default=2,
    show_default=True,
    help="Noise profiles per direction (charge-only, discharge-only pulses of the library) for --noise-trials.",
)
@click.option(
    "--noise",
    "noise_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="Noise model that weights the information: noise.toml or a campaign's noise.json [default: the paper's].",
)
@click.option(
    "--rest-before",
    "rest_before_s",
    type=float,
    default=1800.0,
    show_default=True,
    help="Rest before every profile [s]: the fit starts each profile from a relaxed cell, and a "
    "slow electrode needs longer (nca18650-true: 0.79 mV of start-state error after 30 min, 0.08 mV after 2 h).",
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
    noise_trials: int,
    noise_per_direction: int,
    noise_file: str | None,
    rest_before_s: float,
    unweighted: bool,
) -> None:
    """Select M library profiles per parameter group (convex relaxation, rounding, checks) and write the plan.

    Writes the plan TOML (whole experiment), one TOML per group, the design's summary <plan>.summary.json beside
    it, and a figure of the relaxed weights.
    """
    from battlab.design import workflow
    from battlab.noise import load

    check_output_path(output, create=True)
    noise = load(noise_file) if noise_file else None
    if Path(output).suffix.lower() != ".toml":  # as write_plan requires, but before the design is computed
        raise InputError(f"{output}: the plan is a .toml file")
    costs = None
    if costs_file:
        try:
            raw = json.loads(Path(costs_file).read_text())
            costs = {str(k_): float(v) for k_, v in raw.items()}
        except (OSError, json.JSONDecodeError, AttributeError, TypeError, ValueError) as exc:
            raise InputError(f"{costs_file}: expected a JSON object {{profile id: cost}} ({exc})") from None
    rep = workflow.design(
        store_path,
        output,
        criterion=criterion,
        M=M,
        budget=budget,
        cost=cost,
        costs=costs,
        k=k,
        groups_spec=groups_spec,
        cumulative=cumulative,
        exact=exact,
        include_flagged=include_flagged,
        solver=solver,
        singular=singular,
        unweighted=unweighted,
        noise=noise,
        noise_trials=noise_trials,
        noise_per_direction=noise_per_direction,
        rest_before_s=rest_before_s,
    )
    _note(rep.note)
    console = make_console()
    _print_design(console, rep.designs, rep.meta, rep.settings, rep.source, rep.n_candidates, rep.solve_seconds)
    if rep.window_excluded:
        ids = ", ".join(str(p) for p in list(rep.window_excluded)[:10]) + (
            " …" if len(rep.window_excluded) > 10 else ""
        )
        console.print(
            f"{len(rep.window_excluded)} profiles leave the plan's SOC or voltage window on the design cell "
            f"(excluded: {ids}; reasons in the summary's 'excluded')"
        )
    if rep.window is not None:
        console.print(
            f"plan checked on cell {rep.window.cell} from {rep.window.start}: its {len(rep.window.profiles)} profiles "
            "keep the SOC and voltage window"
        )
    trials = json.loads(rep.files.summary.read_text()).get("noise_trials")
    if trials:
        console.print(
            f"the plan starts with {trials['trials']} noise trials of profiles {', '.join(trials['profiles'])} "
            "(labelled 'noise: ...'; `battlab fit` fits the noise model from them)"
        )
    files = rep.files
    console.print(f"wrote {files.plan}, {', '.join(str(p) for p in files.groups)}, {files.summary}, {rep.figure}")


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
