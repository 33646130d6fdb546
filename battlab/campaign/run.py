"""Run a campaign: its stages through the stage runner, then ``summary.json`` in the campaign directory.

``summary.json``: the identity, per stage its status (ran or skipped this time), wall time [s], lab hours and summary,
the totals, the recovery table (truth, estimate, interval) on the virtual lab and the validation RMSE table (nominal,
conventional, OED) per validation test. A failing stage raises :class:`CampaignFailed` naming it; the finished stages
stay recorded, so a rerun resumes at the failed one.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from battlab.campaign.config import CampaignConfig
from battlab.campaign.pipeline import Campaign, stages
from battlab.campaign.stages import StageRecord, Subscriber, run_stages
from battlab.campaign.tester import Tester


class CampaignFailed(Exception):
    """A stage failed: ``stage`` and the one-line ``reason``."""

    def __init__(self, stage: str, reason: str, directory: Path) -> None:
        self.stage, self.reason, self.directory = stage, reason, directory
        super().__init__(
            f"campaign stage {stage!r} failed: {reason} (finished stages kept in {directory}; rerun to resume)"
        )


def identity(config: CampaignConfig, tester: Tester) -> dict[str, Any]:
    """What a campaign directory is about: the cells, the tester, the variant (a different one is refused)."""
    from battlab import __version__

    return {
        "start": config.campaign.start,
        "tester": tester.describe(),
        "quick": config.quick,
        "battlab": __version__,
    }


def run_campaign(
    config: CampaignConfig,
    tester: Tester,
    directory: str | Path,
    subscribers: Sequence[Subscriber] = (),
) -> dict[str, Any]:
    """Run (or resume) the campaign in ``directory``; returns the summary written to ``summary.json``."""
    directory = Path(directory).resolve()  # the stages name their files relative to it (a relative -o works too)
    camp = Campaign(config, tester, directory)
    todo = stages(camp)
    current: list[str] = [""]

    def track(ev: Any) -> None:
        if ev.kind == "start":
            current[0] = ev.task

    t0 = time.perf_counter()
    try:
        records = run_stages(directory, todo, identity(config, tester), [track, *subscribers])
    except KeyboardInterrupt:
        raise
    except Exception as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if not isinstance(exc, (OSError, ValueError)) and type(exc).__name__ not in ("InputError", "RunFailed"):
            reason = f"{type(exc).__name__}: {reason}"
        if not current[0]:
            raise
        raise CampaignFailed(current[0], reason, directory) from exc
    summary = summarise(records, config, tester, time.perf_counter() - t0)
    tmp = directory / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1, default=str))
    os.replace(tmp, directory / "summary.json")
    return summary


def summarise(records: Sequence[StageRecord], config: CampaignConfig, tester: Tester, wall_s: float) -> dict[str, Any]:
    by = {r.name: r for r in records}
    out: dict[str, Any] = {
        "identity": identity(config, tester),
        "config": config.as_dict(),
        "stages": [
            {
                "name": r.name,
                "status": r.status,
                "wall_s": r.wall_s,
                "lab_hours": r.output.lab_hours,
                "files": dict(r.output.files),
                "summary": r.output.summary,
            }
            for r in records
        ],
        "wall_s_this_run": wall_s,
        "wall_s_stages": sum(r.wall_s for r in records),
        "lab_hours": sum(r.output.lab_hours for r in records),
        "report": "report.html" if "report" in by else None,
    }
    if "fit" in by and "recovery" in by["fit"].output.summary:
        out["recovery"] = [
            {k: r.get(k) for k in ("parameter", "truth", "estimate", "ci95", "covered", "truth_on_bound", "trusted")}
            | {"untrusted_because": r.get("untrusted_because", [])}
            for r in by["fit"].output.summary["recovery"]
        ]
        out["recovery_invariants"] = [
            {k: r.get(k) for k in ("parameter", "truth", "estimate", "ci95", "covered", "trusted")}
            | {"untrusted_because": r.get("untrusted_because", [])}
            for r in by["fit"].output.summary.get("recovery_invariants", [])
        ]
    if "equilibrium" in by and "ci95" in by["equilibrium"].output.summary:
        e = by["equilibrium"].output.summary
        truth = e.get("truth") if isinstance(e.get("truth"), dict) else {}
        out["equilibrium"] = {
            "converged": e.get("converged"),
            "trusted": e.get("trusted"),
            "untrusted_because": e.get("untrusted_because", []),
            "estimates": {
                k: {"estimate": e.get(k), "ci95": ci}
                | {x: truth[k][x] for x in ("truth", "bias", "covered") if isinstance(truth.get(k), dict)}
                for k, ci in e["ci95"].items()
            },
        }
    if "validation" in by:
        v = by["validation"].output.summary
        tests = list(next(iter(v["rmse_mV"].values()))) if v["rmse_mV"] else []
        out["validation_rmse_mV"] = {
            t: {label: v["rmse_mV"][label][t] for label in ("nominal", "conventional", "OED") if label in v["rmse_mV"]}
            for t in tests
        }
        out["validation_reference"] = v.get("reference")
    return out
