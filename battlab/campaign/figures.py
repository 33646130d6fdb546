"""The campaign's own figures (PNG): OCV fit, noise model, parameters with intervals, capacity checks."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    _plt().close(fig)
    return path


def ocv_fit(t: np.ndarray, current: np.ndarray, voltage: np.ndarray, cell: Cell, path: Path) -> Path:
    """The slow cycle's voltage against charge passed, and the fitted cell's OCV."""
    plt = _plt()
    q = np.concatenate([[0.0], np.cumsum(current[:-1] * np.diff(t))]) / 3600.0
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(q - q.min(), voltage, "k.", ms=1.5, label="C/20 cycle (measured)")
    soc = np.linspace(0, 1, 200)
    ax.plot(soc * cell.capacity(), cell.ocv(soc), "C1", lw=1.5, label=f"fitted OCV ({cell.capacity():.3f} Ah)")
    ax.set_xlabel("charge from empty [Ah]")
    ax.set_ylabel("voltage [V]")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def noise_model(rows: Sequence[Mapping[str, Any]], model: Any, path: Path) -> Path:
    """Repeated-trial noise q against input intensity (eq. 36-38) and the fitted lines."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    x = np.array([r["intensity"] for r in rows]) if rows else np.array([1.0])
    grid = np.linspace(0.0, max(float(x.max()) * 1.2, 1.0), 100)
    for d, c in (("charge", "C0"), ("discharge", "C3")):
        pts = [r for r in rows if r["direction"] == d]
        if pts:
            ax.plot([r["intensity"] for r in pts], [1e6 * r["q_V"] for r in pts], "o", color=c, label=f"{d} trials")
        f = model.q_charge if d == "charge" else model.q_discharge
        ax.plot(grid, [1e6 * f(g) for g in grid], "-", color=c, lw=1, label=f"{d} model")
    ax.set_xlabel("input intensity Ĩ [A s^½]")
    ax.set_ylabel("noise q [µV]")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def parameters(rows: Sequence[Mapping[str, Any]], path: Path, conventional: Mapping[str, Any] | None = None) -> Path:
    """Estimates with 95 % intervals on the normalised axis θ̄ (bounds at 0 and 1), against start and truth."""
    plt = _plt()
    n = len(rows)
    fig, ax = plt.subplots(figsize=(7, 0.35 * n + 1.2))
    for k, r in enumerate(rows):
        y = n - 1 - k
        tb = r["theta_bar"]
        lo, hi = r.get("ci_bar") or (None, None)
        if lo is not None:
            ax.plot([lo, hi], [y, y], "C0-", lw=2)
        ax.plot(tb["estimate"], y, "C0o", ms=5, label="OED estimate, 95 % interval" if k == 0 else None)
        ax.plot(tb["start"], y, "kx", ms=6, label="start" if k == 0 else None)
        if tb.get("truth") is not None:
            ax.plot(tb["truth"], y, "C3*", ms=8, label="truth" if k == 0 else None)
        if conventional and r["parameter"] in conventional:
            ax.plot(conventional[r["parameter"]], y + 0.25, "C2d", ms=4, label="conventional" if k == 0 else None)
    ax.set_yticks(range(n), [r["parameter"] for r in rows][::-1], fontsize=8)
    ax.axvline(0, color="0.6", lw=0.8)
    ax.axvline(1, color="0.6", lw=0.8)
    ax.set_xlim(-0.25, 1.25)
    ax.set_xlabel("normalised parameter θ̄ (bounds at 0 and 1)")
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(True, axis="x", alpha=0.3)
    return _save(fig, path)


def capacity(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], path: Path) -> Path:
    """The capacity checks' C/3 discharges: voltage against discharged charge, before and after the campaign."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for label, (q, v) in curves.items():
        ax.plot(q, v, lw=1.2, label=f"{label} ({q[-1]:.4f} Ah)")
    ax.set_xlabel("discharged [Ah]")
    ax.set_ylabel("voltage [V]")
    ax.legend()
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def profiles(items: Sequence[tuple[str, np.ndarray, np.ndarray]], path: Path) -> Path:
    """The selected inputs: current against time, one panel each."""
    plt = _plt()
    n = max(len(items), 1)
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.3 * n + 0.6), squeeze=False)
    for ax, (label, t, i) in zip(axes[:, 0], items, strict=False):
        ax.step(t, i, where="post", lw=0.8)
        ax.set_ylabel("I [A]", fontsize=8)
        ax.set_title(label, fontsize=8, loc="left")
    axes[-1, 0].set_xlabel("time [s]")
    return _save(fig, path)
