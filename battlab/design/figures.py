"""Identifiability and design figures: the ranking bars (paper Fig. 4), the perturbation plot (Fig. 5), the
relaxed design weights."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from battlab import parameters
from battlab.design.identifiability import Ranking

COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def _plt():  # noqa: ANN202 (matplotlib.pyplot)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def ranking_bars(ranking: Ranking, groups: Sequence[Sequence[str]], path: str | Path) -> Path:
    """Fig. 4: mean orthogonalised magnitude per parameter (log scale, by rank, coloured by group), with the
    stacked pivoted-QR magnitude (scaled to the same total) as markers."""
    plt = _plt()
    group_of = {n: k for k, g in enumerate(groups) for n in g}
    order = ranking.order
    names = [ranking.names[i] for i in order]
    fig, ax = plt.subplots(figsize=(10, 4.2))
    x = np.arange(len(order))
    ax.bar(x, ranking.mean[order], color=[COLOURS[group_of.get(n, 0) % len(COLOURS)] for n in names])
    st = ranking.stacked[order] * (ranking.mean.sum() / max(ranking.stacked.sum(), 1e-300))
    ax.plot(x, st, "k.", label="pivoted QR of the stacked library (scaled)")
    ax.set_yscale("log")
    ax.set_xticks(x, [parameters.SPECS[n].symbol if n in parameters.SPECS else n for n in names], rotation=45)
    ax.set_ylabel("mean orthogonalised magnitude")
    for k in range(len(groups)):
        ax.bar([0], [0], color=COLOURS[k % len(COLOURS)], label=f"group {k + 1}")
    ax.legend(fontsize=8)
    ax.set_title(f"Orthogonalised sensitivity ranking over {len(ranking.ids)} profiles")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def perturbation(
    runs: Sequence[dict[str, Any]],
    path: str | Path,
    title: str = "",
) -> Path:
    """Fig. 5: voltage of one profile with one parameter per group set to several θ̄ values.

    ``runs``: one dict per panel: {"parameter", "group", "curves": [(theta_bar, t, V), …]}.
    """
    plt = _plt()
    n = len(runs)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.4 * n), sharex=True, squeeze=False)
    for ax, r in zip(axes[:, 0], runs, strict=True):
        cmap = plt.get_cmap("viridis")
        curves = r["curves"]
        for j, (tb, t, v) in enumerate(curves):
            ax.plot(t, v, color=cmap(j / max(len(curves) - 1, 1)), lw=1, label=f"θ̄ = {tb:.2f}")
        sym = parameters.SPECS[r["parameter"]].symbol if r["parameter"] in parameters.SPECS else r["parameter"]
        ax.set_title(f"group {r['group']}: {sym}", fontsize=9)
        ax.set_ylabel("V [V]")
        ax.legend(fontsize=7, ncol=len(curves), loc="best")
    axes[-1, 0].set_xlabel("t [s]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def design_weights(designs: Sequence[Any], path: str | Path) -> Path:
    """Relaxed design weights M·η per group (1 = selected in full), selected profiles marked."""
    plt = _plt()
    n = len(designs)
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 3), squeeze=False)
    for ax, d in zip(axes[0], designs, strict=True):
        M = len(d.selected)
        items = sorted(d.eta.items(), key=lambda kv: -kv[1])[: 3 * M]
        ids = [str(k) for k, _ in items]
        ax.bar(
            range(len(items)),
            [v * M for _, v in items],
            color=["#2ca02c" if k in d.selected else "#aaaaaa" for k, _ in items],
        )
        ax.set_xticks(range(len(items)), ids, rotation=90, fontsize=7)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"group {d.index} ({d.criterion})", fontsize=9)
    axes[0, 0].set_ylabel("M·η (relaxed)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
