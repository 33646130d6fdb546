"""The optimal selection per group with the campaign's fitted noise model.

:func:`battlab.design.workflow.design` weights the Fisher information with the paper's default noise model (it has no
``noise`` argument); the campaign fits its own from repeated trials (eqs. 36-40), so this runs the same steps
(information, groups, convex design with rounding, plan files) with that model.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from battlab.noise import NoiseModel


def design_with_noise(
    store_path: str | Path,
    output: str | Path,
    groups: Sequence[Sequence[str]],
    noise: NoiseModel,
    *,
    criterion: str = "D",
    M: int = 5,
) -> dict[str, Any]:
    """Select ``M`` profiles per (cumulative) group under ``noise``; writes the plan TOML, its
    ``plan.summary.json`` and a weights figure; returns the design summary (with ``"figure"``: its path)."""
    from battlab.design import figures as figs
    from battlab.design import groups as gd
    from battlab.design import information
    from battlab.design import plan as planmod
    from battlab.design.criteria import Criterion
    from battlab.design.sweep import SensitivityStore

    store = SensitivityStore.open(store_path)
    with store:
        t0 = time.perf_counter()
        info = information.load(store, noise)
        conv = information.conventional(store, noise)
        settings = gd.Settings(M=M, criterion=Criterion.of(criterion), cumulative=True, on_singular="project")
        designs = gd.design_groups(info, [list(g) for g in groups], settings, conv)
        solve = time.perf_counter() - t0
        meta = {m["id"]: m for m in info.meta}
        files = planmod.write_plan(
            designs,
            store,
            output,
            criterion=settings.criterion.value,
            solve_seconds=solve,
            extra={
                "M": M,
                "noise_model": noise.__dict__,
                "n_candidates": len(info),
                "selected_profiles": {str(pid): meta[pid] for d in designs for pid in d.selected},
            },
        )
        fig = figs.design_weights(designs, Path(output).with_suffix(".weights.png"))
    summary = json.loads(Path(files.summary).read_text())
    out = {
        "criterion": summary["criterion"],
        "groups": [
            {"parameters": g["parameters"], "selected": g["selected"], "logdet": g.get("logdet")}
            for g in summary["groups"]
        ],
        "solve_seconds": solve,
        "n_candidates": len(info),
        "selected_profiles": {str(pid): _meta(meta[pid]) for d in designs for pid in d.selected},
        "figure": str(Path(fig).resolve().relative_to(Path(output).resolve().parent.parent)),
    }
    return out


def _meta(m: dict[str, Any]) -> dict[str, Any]:
    return {k: m[k] for k in ("kind", "soc0", "duration") if k in m} | {"params": m.get("params")}
