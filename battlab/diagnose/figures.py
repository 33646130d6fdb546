"""Residual figures: the error against time with the current beneath, the error conditioned on each feature, and
its autocorrelation and spectrum (what a modelling engineer looks at before naming a cause)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from battlab.diagnose.residuals import SLOW_HZ, ResidualAnalysis


def _plt():  # noqa: ANN202 (matplotlib.pyplot)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def residual_vs_time(a: ResidualAnalysis, path: str | Path, title: str = "") -> Path:
    """Residual [mV] over time [h], with the current [A] beneath on a shared axis."""
    plt = _plt()
    fig, (ax, axi) = plt.subplots(2, 1, sharex=True, figsize=(9, 5), height_ratios=(2, 1))
    th = (a.t - a.t[0]) / 3600.0
    ax.plot(th, 1e3 * a.residual, lw=0.6, color="#d62728")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_ylabel("measured − simulated [mV]")
    ax.set_title(title or f"RMSE {1e3 * a.rmse:.2f} mV, bias {1e3 * a.bias:+.2f} mV")
    axi.plot(th, a.features["current"], lw=0.6, color="#1f77b4")
    axi.set_ylabel("current [A]\n(+ = charge)")
    axi.set_xlabel("time [h]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def conditional_errors(a: ResidualAnalysis, path: str | Path) -> Path:
    """Per feature: bias and RMSE [mV] per quantile bin, features ordered by how much the error depends on them."""
    plt = _plt()
    feats = sorted(a.by_feature.values(), key=lambda f: f.spread, reverse=True)
    n = len(feats)
    cols = 3
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(10, 2.6 * rows), squeeze=False)
    for ax, f in zip(axes.flat, feats, strict=False):
        mid = 0.5 * (f.edges[1:] + f.edges[:-1])
        ax.plot(mid, 1e3 * f.rmse, "o-", color="#d62728", label="RMSE")
        ax.plot(mid, 1e3 * f.bias, "s--", color="#1f77b4", label="bias")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel(f"{f.name} [{f.unit}]")
        ax.set_title(f"r = {f.correlation:+.2f}", fontsize=9)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].set_ylabel("error [mV]")
    axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def whiteness(a: ResidualAnalysis, path: str | Path) -> Path:
    """Autocorrelation against lag [s] and the power spectrum, the slow band (< 1/600 Hz) shaded."""
    plt = _plt()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
    dt = float(np.median(np.diff(a.t))) if a.t.size > 1 else 1.0
    lags = np.arange(a.acf.size) * dt
    ax1.plot(lags, a.acf, color="#2ca02c")
    ax1.axhline(1.0 / np.e, color="k", ls=":", lw=0.8)
    band = 1.96 / np.sqrt(a.residual.size)
    ax1.fill_between(lags, -band, band, color="0.85", label="white noise (95 %)")
    ax1.set_xlabel("lag [s]")
    ax1.set_ylabel("autocorrelation")
    ax1.set_title(f"decorrelation {a.decorrelation_s:.0f} s, Ljung–Box p = {a.ljung_box_p:.2g}", fontsize=9)
    ax1.legend(fontsize=8)
    ok = a.freq > 0
    ax2.loglog(a.freq[ok], a.psd[ok], color="#9467bd")
    ax2.axvspan(a.freq[ok].min(), SLOW_HZ, color="0.9")
    ax2.set_xlabel("frequency [Hz]")
    ax2.set_ylabel("PSD [V² Hz⁻¹]")
    ax2.set_title(f"{100 * a.slow_fraction:.0f} % of the power below 1/600 Hz", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
