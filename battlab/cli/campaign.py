"""``battlab campaign``: the whole loop as one command (see :mod:`battlab.campaign.pipeline`).

Exit codes: 0 finished, 1 a stage failed (one line naming the stage and the reason; the finished stages are kept and
a rerun resumes), 2 a user error (bad config, URL, directory), 130 interrupted.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import click

from protocols.errors import InputError


class StageDisplay:
    """Rich progress on stderr: one bar for the whole campaign (stages done of all) and one for the running stage;
    each finished or reused stage is one line with its wall time."""

    def __init__(self, *, quiet: bool = False) -> None:
        self.quiet = quiet
        self._bar: Any = None
        self._overall: Any = None
        self._stage: Any = None

    def _start(self, total: int) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from battlab.cli.console import make_console

        self._bar = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=make_console(stderr=True),
            transient=True,
        )
        self._bar.start()
        self._overall = self._bar.add_task("campaign", total=total)

    def __call__(self, ev: Any) -> None:
        info = ev.payload
        if self.quiet or info is None:
            return
        if self._bar is None:
            self._start(info.total)
        bar = self._bar
        label = f"[{info.index + 1}/{info.total}] {info.title or ev.task}"
        if ev.kind == "start":
            self._stage = bar.add_task(label, total=None)
        elif ev.kind == "advance" and self._stage is not None:
            bar.update(self._stage, total=max(ev.total, 1), completed=ev.done, description=f"{label}: {ev.text}")
        elif ev.kind in ("stop", "skipped", "failed"):
            if self._stage is not None:
                bar.remove_task(self._stage)
                self._stage = None
            what = {"stop": f"done in {info.wall_s:.1f} s", "skipped": "unchanged (kept)", "failed": "FAILED"}[ev.kind]
            bar.console.print(f"{label}: {what}")
            bar.advance(self._overall)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None


@click.command("campaign")
@click.option(
    "--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), default=None, help="Campaign TOML."
)
@click.option(
    "--tester", type=click.Choice(["virtual"]), default=None, help="The in-process virtual tester (the default)."
)
@click.option("--cycler", "cycler_url", default=None, help="Cycler URL of a real bench (with --chamber).")
@click.option("--chamber", "chamber_url", default=None, help="Chamber URL of a real bench (with --cycler).")
@click.option("--limits", "limits_path", default=None, help="Instrument limits TOML (real instruments).")
@click.option("--quick", is_flag=True, help="The reduced demonstration campaign (a few minutes on the virtual tester).")
@click.option(
    "-o",
    "--output",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("campaign"),
    show_default=True,
    help="Campaign directory (created; rerun the same command to resume).",
)
@click.option("--quiet", is_flag=True, help="No progress display.")
def campaign(
    config_path: Path | None,
    tester: str | None,
    cycler_url: str | None,
    chamber_url: str | None,
    limits_path: str | None,
    quick: bool,
    output: Path,
    quiet: bool,
) -> None:
    """Run the whole loop: capacity check, OCV test, equilibrium, library, sweep, groups, noise model, designs,
    designed experiments, cumulative fits, conventional baseline, validation, diagnosis, capacity check, BPX export,
    report. Writes OUTPUT/report.html and OUTPUT/summary.json."""
    from battlab.campaign import config as C
    from battlab.campaign.pipeline import STAGE_NAMES
    from battlab.campaign.run import CampaignFailed, run_campaign
    from battlab.campaign.tester import Tester

    if (cycler_url is None) != (chamber_url is None):
        raise InputError("give both --cycler and --chamber for a real bench (or neither for the virtual tester)")
    if tester is not None and cycler_url is not None:
        raise InputError("give --tester virtual or --cycler/--chamber, not both")
    from battlab.io.paths import check_output_path

    cfg = C.load(config_path, STAGE_NAMES)
    if quick:
        cfg = C.quick(cfg)
    if cycler_url is not None:
        t = Tester(
            cycler_url.strip(),
            chamber_url.strip(),
            truth=cfg.campaign.truth,
            seed=cfg.campaign.seed,
            limits_path=limits_path,
        )  # type: ignore[union-attr]
    else:
        t = Tester(truth=cfg.campaign.truth, seed=cfg.campaign.seed)
    t.preflight()  # the limits file and both instruments, before the campaign directory is touched
    if t.virtual:  # the hidden cell (it may carry catalog extensions) and the start cell load, before anything runs
        from battlab.cell import Cell

        start, truth = Cell.load(cfg.campaign.start), Cell.load(cfg.campaign.truth)
        if start.extensions and set(truth.extensions) - set(start.extensions):
            raise InputError(
                f"campaign: the truth's extensions {sorted(truth.extensions)} and the start cell's "
                f"{sorted(start.extensions)} are different models; start from the base cell"
            )
        _check_truth_in_reach(truth)
    check_output_path(output, directory=True, create=True)
    display = StageDisplay(quiet=quiet)
    try:
        with _log_to(output / "campaign.log"):
            summary = run_campaign(cfg, t, output, [display])
    except CampaignFailed as exc:
        display.close()
        click.echo(f"error: campaign stage {exc.stage} failed: {exc.reason}", err=True)
        click.echo(f"  finished stages are kept in {exc.directory}; rerun the same command to resume", err=True)
        click.echo(f"  the instruments' and runner's messages are in {output / 'campaign.log'}", err=True)
        sys.exit(1)
    finally:
        display.close()
    click.echo(
        f"campaign finished: {output / 'report.html'} and {output / 'summary.json'} "
        f"({summary['lab_hours']:.1f} lab hours, {summary['wall_s_this_run']:.0f} s this run)"
    )
    v = summary.get("validation_rmse_mV")
    if v:
        for test, row in v.items():
            click.echo("  " + test + ": " + ", ".join(f"{k} {x:.2f} mV" for k, x in row.items()))
    dg = next((st["summary"] for st in summary["stages"] if st["name"] == "diagnosis"), None)
    if dg is not None:
        g = dg.get("extension_gain") or {}
        found = f"cause {dg['cause']}" if dg.get("cause") else "no cause named"
        if not dg.get("cause") and dg.get("suggested"):
            found = f"no cause confirmed ({dg['suggested']} named by the diagnosis, not kept)"
        elif not dg.get("cause") and g.get("cause"):
            found = f"no cause confirmed ({', '.join(t['cause'] for t in dg.get('extended', []))} extended, not kept)"
        if g.get("rmse_after_mV") is not None:
            found += f", held-out RMSE {g['rmse_before_mV']:.2f} -> {g['rmse_after_mV']:.2f} mV after extending"
        rounds = dg.get("rounds") or []
        if rounds:
            found += f" ({len(rounds)} deciding experiment(s), {dg.get('lab_hours', 0):.1f} lab h)"
        click.echo(f"  diagnosis: {found}")


def _check_truth_in_reach(truth: Any) -> None:
    """A hidden extension whose value lies outside the range a fit searches cannot be found by the campaign (the
    extended model cannot represent it): one line before anything runs."""
    from battlab import parameters

    for key in truth.extensions:
        for p in parameters.EXTENSIONS[key]:
            v = float(truth.value(p.qualified))
            if not p.lower <= v <= p.upper:
                raise InputError(
                    f"campaign: the truth's {p.qualified} = {v:g} {p.unit} lies outside the range a fit searches "
                    f"({p.lower:g} to {p.upper:g} {p.unit}): the extended model cannot represent it"
                )


@contextlib.contextmanager
def _log_to(path: Path) -> Iterator[None]:
    """The instruments' and the runner's messages (an output turned off at a cut-off, a run aborted at a limit) go to
    ``path`` (appended, created with the first message), not to the terminal: the stages' outcomes are in the
    summary and the run-log health, and a failed stage is its one error line."""
    handler = logging.FileHandler(path, mode="a", encoding="utf-8", delay=True)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    level = root.level
    root.addHandler(handler)
    root.setLevel(min(level or logging.WARNING, logging.INFO))
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(level)
        handler.close()
