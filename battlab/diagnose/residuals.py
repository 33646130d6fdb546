"""Residual analysis: what the simulation gets wrong, when, and how the error is structured.

Given measured and simulated voltage on one time grid (and the current, positive = charge), this computes the
features a modelling engineer conditions on — time, SOC, current, |current|, direction, rate of change of
current, temperature, charge passed, time since the last rest — and, per feature, the residual's correlation and
its bias and RMSE in quantile bins; the residual's autocorrelation, a Ljung–Box whiteness test and its
decorrelation time; its power spectrum and the share of its power in slow (< 1/600 Hz) variations; and s², the
mean squared residual over the noise model's variance (≈ 1 when the model is right and the noise model is).

Residual = measured − simulated [V].
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal, stats

#: |I| below this counts as rest [A]
REST_A = 1e-3
#: frequency below which residual power counts as slow drift [Hz]
SLOW_HZ = 1.0 / 600.0


def measured_noise_variance(voltage: np.ndarray, current: np.ndarray, step_A: float, trim: float = 0.01) -> float:
    """The voltage noise variance [V²] of a log, from the data themselves: the second differences of the voltage
    (white noise of variance σ² gives Var = 6 σ²) over the samples whose current and both neighbours' agree within
    ``step_A`` [A] (a step's jump and the relaxation right after it are left out), the largest ``trim`` share
    dropped. What the cell does within three samples at one current is far below the tester's noise at 1 s;
    the estimate is NaN with fewer than 30 such samples."""
    v = np.asarray(voltage, float)
    i = np.asarray(current, float)
    if v.size < 3:
        return float("nan")
    d2 = v[2:] - 2.0 * v[1:-1] + v[:-2]
    steady = (np.abs(i[1:-1] - i[:-2]) <= step_A) & (np.abs(i[2:] - i[1:-1]) <= step_A)
    if v.size > 3:
        steady[1:] &= np.abs(i[1:-2] - i[:-3]) <= step_A  # not the first sample after a step either
    x = np.sort(d2[steady & np.isfinite(d2)] ** 2)
    if x.size < 30:
        return float("nan")
    x = x[: max(1, int(round((1.0 - trim) * x.size)))]
    return float(np.mean(x) / 6.0)


@dataclass(frozen=True)
class FeatureStats:
    """The residual conditioned on one feature: correlation and per-bin bias and RMSE."""

    name: str
    unit: str
    correlation: float
    edges: np.ndarray  # bin edges of the feature (quantiles)
    bias: np.ndarray  # mean residual per bin [V]
    rmse: np.ndarray  # RMSE per bin [V]
    count: np.ndarray  # samples per bin

    @property
    def spread(self) -> float:
        """Largest minus smallest per-bin RMSE [V]: how strongly the error depends on this feature."""
        ok = self.count > 0
        return float(np.ptp(self.rmse[ok])) if np.any(ok) else 0.0


@dataclass(frozen=True)
class ResidualAnalysis:
    t: np.ndarray
    residual: np.ndarray  # measured − simulated [V]
    features: Mapping[str, np.ndarray]
    by_feature: Mapping[str, FeatureStats]
    rmse: float
    bias: float
    max_abs: float
    s2: float | None  # mean r² / noise variance (None without a noise model)
    acf: np.ndarray  # autocorrelation at lags 0..len−1 samples
    decorrelation_s: float  # first lag where the autocorrelation falls below 1/e [s]
    ljung_box_p: float  # whiteness test over the first lags (small: not white)
    freq: np.ndarray  # [Hz]
    psd: np.ndarray  # [V² Hz⁻¹]
    slow_fraction: float  # share of the residual's power below SLOW_HZ

    def summary(self) -> dict[str, object]:
        """JSON-able headline numbers, in mV and s; features ordered by how much the error depends on them."""
        order = sorted(self.by_feature.values(), key=lambda f: f.spread, reverse=True)
        return {
            "rmse_mV": 1e3 * self.rmse,
            "bias_mV": 1e3 * self.bias,
            "max_abs_mV": 1e3 * self.max_abs,
            "s2": self.s2,
            "decorrelation_s": self.decorrelation_s,
            "ljung_box_p": self.ljung_box_p,
            "slow_fraction": self.slow_fraction,
            "features": [
                {"name": f.name, "unit": f.unit, "correlation": f.correlation, "rmse_spread_mV": 1e3 * f.spread}
                for f in order
            ],
        }


UNITS = {
    "time": "s",
    "soc": "1",
    "current": "A",
    "abs_current": "A",
    "direction": "1",
    "dI_dt": "A/s",
    "temperature": "degC",
    "charge_passed": "Ah",
    "since_rest": "s",
}


def features(
    t: np.ndarray, current: np.ndarray, soc: np.ndarray | None = None, temperature: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """The conditioning features on the sample grid (current positive = charge, zero-order hold)."""
    t = np.asarray(t, float)
    i = np.asarray(current, float)
    dt = np.diff(t, append=t[-1])
    out = {
        "time": t - t[0],
        "current": i,
        "abs_current": np.abs(i),
        "direction": np.sign(np.where(np.abs(i) < REST_A, 0.0, i)),
        "dI_dt": np.gradient(i, t) if t.size > 1 else np.zeros_like(i),
        "charge_passed": np.concatenate([[0.0], np.cumsum(np.abs(i[:-1]) * np.diff(t))]) / 3600.0,
    }
    since = np.zeros_like(t)
    last_rest = t[0]
    for k in range(t.size):
        if abs(i[k]) < REST_A:
            last_rest = t[k] + dt[k]
        since[k] = max(t[k] - last_rest, 0.0)
    out["since_rest"] = since
    if soc is not None:
        out["soc"] = np.asarray(soc, float)
    if temperature is not None and np.all(np.isfinite(temperature)):
        out["temperature"] = np.asarray(temperature, float)
    return out


def _binned(x: np.ndarray, r: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([x.min(), x.max() + 1e-12])
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    nb = edges.size - 1
    count = np.bincount(idx, minlength=nb).astype(float)
    s1 = np.bincount(idx, r, minlength=nb)
    s2 = np.bincount(idx, r * r, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = np.where(count > 0, s1 / count, np.nan)
        rmse = np.where(count > 0, np.sqrt(s2 / count), np.nan)
    return edges, bias, rmse, count


def autocorrelation(r: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation at lags 0..max_lag (FFT, biased estimator)."""
    x = r - r.mean()
    n = x.size
    f = np.fft.rfft(x, 2 * n)
    acov = np.fft.irfft(f * np.conj(f))[: max_lag + 1] / n
    return acov / acov[0] if acov[0] > 0 else np.zeros(max_lag + 1)


def analyse(
    t: np.ndarray,
    measured: np.ndarray,
    simulated: np.ndarray,
    current: np.ndarray,
    *,
    soc: np.ndarray | None = None,
    temperature: np.ndarray | None = None,
    noise_variance: np.ndarray | float | None = None,
    n_bins: int = 8,
    max_lag_s: float = 1800.0,
) -> ResidualAnalysis:
    """Residual analysis of one data set (arrays on one time grid [s]; voltages [V]; current [A], + = charge)."""
    t = np.asarray(t, float)
    r = np.asarray(measured, float) - np.asarray(simulated, float)
    ok = np.isfinite(r)
    if not np.any(ok):
        raise ValueError("no finite residual: the simulation and the data share no valid sample")
    t, r = t[ok], r[ok]
    cur = np.asarray(current, float)[ok]
    feats = features(
        t,
        cur,
        None if soc is None else np.asarray(soc, float)[ok],
        None if temperature is None else np.asarray(temperature, float)[ok],
    )
    by = {}
    for name, x in feats.items():
        edges, bias, rmse, count = _binned(x, r, n_bins)
        corr = float(np.corrcoef(x, r)[0, 1]) if np.std(x) > 0 and np.std(r) > 0 else 0.0
        by[name] = FeatureStats(name, UNITS.get(name, ""), corr, edges, bias, rmse, count)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    max_lag = int(min(max_lag_s / dt, r.size - 1))
    acf = autocorrelation(r, max(max_lag, 1))
    below = np.nonzero(acf < 1.0 / np.e)[0]
    decor = float(below[0] * dt) if below.size else float(max_lag * dt)
    lb_lags = min(20, r.size - 2)
    if lb_lags >= 1:
        k = np.arange(1, lb_lags + 1)
        q = r.size * (r.size + 2) * np.sum(acf[1 : lb_lags + 1] ** 2 / (r.size - k))
        lb_p = float(stats.chi2.sf(q, lb_lags))
    else:
        lb_p = 1.0
    freq, psd = signal.welch(r - r.mean(), fs=1.0 / dt, nperseg=min(r.size, 4096))
    # the slow share from the whole record's periodogram (Welch's segments would hide a drift longer than them)
    f_all, p_all = signal.periodogram(r - r.mean(), fs=1.0 / dt, detrend=False)
    total = float(np.sum(p_all))
    slow = float(np.sum(p_all[(f_all > 0) & (f_all < SLOW_HZ)]) / total) if total > 0 else 0.0
    s2 = None
    if noise_variance is not None:
        nv = np.broadcast_to(np.asarray(noise_variance, float), ok.shape)[ok]
        s2 = float(np.mean(r * r / nv))
    return ResidualAnalysis(
        t=t,
        residual=r,
        features=feats,
        by_feature=by,
        rmse=float(np.sqrt(np.mean(r * r))),
        bias=float(np.mean(r)),
        max_abs=float(np.max(np.abs(r))),
        s2=s2,
        acf=acf,
        decorrelation_s=decor,
        ljung_box_p=lb_p,
        freq=freq,
        psd=psd,
        slow_fraction=slow,
    )
