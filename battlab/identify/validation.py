"""Validation on held-out profiles: RMSE tables like the paper's Tables 12–14 and figures like Figs. 7 and 9.

The reference voltage is the noise-free truth when known (virtual lab; docs/decisions.md: "RMSE against the noise-free
true voltage"), else the measurement. Constant-current discharges are scored up to 90 % of the discharged
capacity as in Table 12 (from full charge, 90 % of the cell's capacity between its voltage limits,
:meth:`Cell.capacity`, or until the true cell reaches V_min, :func:`cut_at_limit`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from protocols.drive_cycles import Cycle, drive_profile
from protocols.profile import Profile


def prediction(forward: ForwardModel, cell: Cell, exp: Experiment) -> tuple[np.ndarray, str | None]:
    """The voltage of ``cell`` under an experiment, NaN where the simulation did not reach (it stopped early:
    a held last value is not a prediction), and why it stopped (None: it covered the experiment)."""
    out = forward.run(
        forward.theta_of(cell), exp.profile, exp.soc0, ambient=exp.ambient, T0=exp.T0, sample_delay=exp.sample_delay
    )
    pred = np.full(exp.voltage.size, np.nan)
    pred[: out.voltage.size] = out.voltage
    return pred, out.ended_by if out.voltage.size < exp.voltage.size else None


def predict(forward: ForwardModel, cell: Cell, exp: Experiment) -> np.ndarray:
    """:func:`prediction`'s voltage (NaN beyond an early stop)."""
    return prediction(forward, cell, exp)[0]


def discharge_profiles(
    cell: Cell, rates: Sequence[float] = (0.5, 1.0), soc0: float = 1.0, depth: float = 0.9
) -> list[tuple[Profile, float]]:
    """Constant-current validation discharges (Table 12): ``depth`` of capacity from ``soc0``, 1-s samples."""
    q, cap = float(cell["Q_nom"]), float(cell.capacity())
    return [
        (Profile.constant(-c * q, depth * cap / q * 3600 / c, 1.0, id=f"{c:g}C discharge", kind="cc"), soc0)
        for c in rates
    ]


def cut_at_limit(forward: ForwardModel, truth: Cell, profile: Profile, soc0: float) -> Profile:
    """``profile`` cut where the true cell reaches a voltage limit (a test ends there), else unchanged."""
    out = forward.run(forward.theta_of(truth), profile, soc0)
    n = out.voltage.size
    if out.ended_by is None or n == profile.t.size:
        return profile
    if n < 10 or out.ended_by.startswith("solver"):
        raise ValueError(f"validation profile {profile.id}: the true cell's simulation failed ({out.ended_by})")
    return Profile(
        profile.t[:n],
        np.r_[profile.current[: n - 1], profile.current[n - 2]],
        id=profile.id,
        kind=profile.kind,
        soc0=soc0,
    )


def validation_profiles(
    forward: ForwardModel, truth: Cell, library: Iterable[Profile], used: Iterable[object] = ()
) -> list[tuple[Profile, float]]:
    """The held-out validation set, (profile, start SOC) each: 0.5C and 1C discharges, a sinusoid and a pulse train
    of ``library`` that are not in ``used`` (ids, compared as text), and the HWFET, US06 and WLTC class 3b drive
    cycles from SOC 0.6 (from 0.8 HWFET's regenerative peaks reach V_max); each cut where the true cell stops."""
    taken = {str(u) for u in used}
    out = [(cut_at_limit(forward, truth, p, s), s) for p, s in discharge_profiles(truth)]
    th = forward.theta_of(truth)
    profiles = list(library)
    for kind in ("sine", "pulse"):
        for p in profiles[7::13]:
            if p.kind == kind and str(p.id) not in taken and forward.run(th, p, p.soc0).ended_by is None:
                out.append((p, p.soc0))
                break
    for cyc in (Cycle.HWFET, Cycle.US06, Cycle.WLTC3B):
        p = drive_profile(cyc, soc0=0.6, id=cyc.name)
        out.append((cut_at_limit(forward, truth, p, 0.6), 0.6))
    return out


def reference(e: Experiment) -> np.ndarray:
    """What a prediction is scored against: the noise-free truth if known, else the data."""
    return e.truth if e.truth is not None else e.voltage


def rmse_table(
    forward: ForwardModel, cells: Mapping[str, Cell], experiments: Sequence[Experiment]
) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, np.ndarray]]]:
    """RMSE [mV] per cell label and experiment, and the predictions (for figures)."""
    table: dict[str, dict[str, float]] = {}
    preds: dict[str, dict[str, np.ndarray]] = {}
    for label, cell in cells.items():
        table[label], preds[label] = {}, {}
        for e in experiments:
            p = predict(forward, cell, e)
            preds[label][e.name] = p
            table[label][e.name] = float(1e3 * np.sqrt(np.nanmean((p - reference(e)) ** 2)))
    return table, preds


def format_table(
    table: Mapping[str, Mapping[str, float]], coverage: Mapping[str, Mapping[str, float]] | None = None
) -> str:
    """Plain-text RMSE table: one row per experiment, one column per cell [mV]; a prediction that stopped early
    shows the share of the data it covered, e.g. ``12.34 (82%)``."""
    labels = list(table)
    names = list(next(iter(table.values()))) if table else []
    w = max([len(n) for n in names] + [10])

    def cell(lab: str, n: str) -> str:
        text = f"{table[lab][n]:.2f}"
        share = (coverage or {}).get(lab, {}).get(n, 1.0)
        return f"{text} ({100 * share:.0f}%)" if share < 1.0 else text

    lines = [f"{'RMSE [mV]':<{w}}  " + "  ".join(f"{lab:>14}" for lab in labels)]
    for n in names:
        lines.append(f"{n:<{w}}  " + "  ".join(f"{cell(lab, n):>14}" for lab in labels))
    return "\n".join(lines)


def plot_cdf(errors: Mapping[str, np.ndarray], path: str | Path, title: str = "") -> Path:
    """CDF of |voltage error| [mV] (Fig. 7 bottom), one line per label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, err in errors.items():
        e = np.sort(np.abs(np.asarray(err, float)))
        ax.plot(e, np.arange(1, e.size + 1) / e.size, label=label)
    ax.set_xscale("log")
    ax.set_xlabel("|voltage error| [mV]")
    ax.set_ylabel("CDF")
    ax.set_title(title)
    ax.legend()
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_correlation(names: Sequence[str], correlation: np.ndarray, path: str | Path, title: str = "") -> Path:
    """Heat map of a parameter correlation matrix (blank where a parameter is not identifiable)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = np.ma.masked_invalid(np.asarray(correlation, float))
    n = len(names)
    fig, ax = plt.subplots(figsize=(1.2 + 0.42 * n, 0.8 + 0.4 * n))
    im = ax.imshow(c, cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(n), names, rotation=90, fontsize=8)
    ax.set_yticks(range(n), names, fontsize=8)
    if n <= 12:
        for i in range(n):
            for j in range(n):
                if not np.ma.is_masked(c[i, j]):
                    ax.text(j, i, f"{c[i, j]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, shrink=0.8, label="correlation")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_validation(e: Experiment, preds: Mapping[str, np.ndarray], path: str | Path) -> Path:
    """Voltage against time (or discharged capacity for CC tests, Fig. 9) for data and each cell, with current."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    t = e.profile.t
    cc = e.profile.kind == "cc"
    x = -np.concatenate([[0.0], np.cumsum(e.profile.current[:-1] * np.diff(t))]) / 3600 if cc else t
    ax.plot(x, e.voltage, "k.", ms=1.5, label="data")
    for label, p in preds.items():
        ax.plot(x, p, lw=1.2, label=f"{label} ({1e3 * np.sqrt(np.nanmean((p - reference(e)) ** 2)):.1f} mV)")
    ax.set_ylabel("voltage [V]")
    ax.set_title(e.name)
    ax.legend(fontsize=8)
    ax2.plot(x, e.profile.current, "C7", lw=0.8)
    ax2.set_ylabel("current [A]")
    ax2.set_xlabel("discharged capacity [Ah]" if cc else "time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
