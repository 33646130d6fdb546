"""How well a cell predicts the held-out part of a diagnosis's data, on every logged channel, and whether one cell's
prediction is better than another's by more than the data's noise can produce.

A prediction is scored by its errors normalised by each channel's noise level (the voltage's and, where logged, the
surface temperature's), so one figure weighs a 1 mV error against 1 mV of noise as a 0.1 K error against 0.1 K.
The comparison of two predictions on the same samples is a paired test over contiguous blocks of time of the log
ratio of their mean squared normalised errors (batch means: honest under the slow, correlated error of a model that
is not the truth).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from battlab.cell import Cell
from battlab.diagnose.data import Part


@dataclass(frozen=True)
class HeldOut:
    """A cell's held-out errors, sample by sample over the held-out parts (NaN where its simulation stopped):
    voltage [V] and temperature [K] errors, their times [s] on one axis, and each row's noise level."""

    eV: np.ndarray
    eT: np.ndarray
    tV: np.ndarray
    tT: np.ndarray
    sV: np.ndarray
    sT: np.ndarray

    @property
    def rmse_mV(self) -> float:
        e = self.eV[np.isfinite(self.eV)]
        return float(1e3 * np.sqrt(np.mean(e**2))) if e.size else float("nan")

    @property
    def rmse_K(self) -> float | None:
        e = self.eT[np.isfinite(self.eT)]
        return float(np.sqrt(np.mean(e**2))) if e.size else None

    @property
    def z(self) -> np.ndarray:
        """Normalised errors, voltage rows then temperature rows."""
        return np.concatenate([self.eV / self.sV, self.eT / self.sT])

    @property
    def t(self) -> np.ndarray:
        return np.concatenate([self.tV, self.tT])

    @property
    def metric(self) -> float:
        """RMS of the normalised errors (1: the noise level)."""
        z = self.z[np.isfinite(self.z)]
        return float(np.sqrt(np.mean(z**2))) if z.size else float("nan")


def held_out(fm: object, cell: Cell, parts: Sequence[Part], temperature: bool = True) -> HeldOut:
    """``cell``'s errors on the held-out samples, each experiment simulated from its start (``fm``: a
    :class:`battlab.identify.forward.ForwardModel` that can run ``cell``)."""
    eV, eT, tV, tT, sV, sT = [], [], [], [], [], []
    offset = 0.0
    for p in parts:
        e = p.experiment
        if p.train >= p.n:
            continue
        out = fm.run(  # type: ignore[attr-defined]
            fm.theta_of(cell), e.profile, e.soc0, ambient=e.ambient, T0=e.T0, sample_delay=e.sample_delay
        )
        k = out.voltage.size
        v = np.full(p.n, np.nan)
        v[:k] = out.voltage
        t = e.profile.t - e.profile.t[0] + offset
        offset = float(t[-1]) + 1.0
        held = p.held
        eV.append((v - e.voltage)[held])
        tV.append(t[held])
        sV.append(np.sqrt(np.broadcast_to(np.asarray(e.variance, float), (p.n,)))[held])
        if temperature and e.has_temperature and out.T_surface is not None:
            assert e.temperature is not None
            T = np.full(p.n, np.nan)
            T[:k] = out.T_surface
            eT.append((T - e.temperature)[held])
            tT.append(t[held])
            sT.append(np.full(held.stop - held.start, np.sqrt(e.t_variance)))

    def cat(x: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(x) if x else np.zeros(0)

    return HeldOut(cat(eV), cat(eT), cat(tV), cat(tT), cat(sV), cat(sT))


def improvement_z(base: HeldOut, candidate: HeldOut, block_s: float) -> float:
    """How many standard errors ``candidate`` predicts the held-out samples better than ``base``: per contiguous block
    of ``block_s`` seconds (at least 8) the log of the ratio of their mean squared normalised errors, and the mean of
    those over its standard error (a t statistic over blocks: honest under slow, correlated error, and unmoved by a
    few blocks with large errors). Positive: the candidate is better. Samples either did not reach are left out."""
    zb, zc = base.z, candidate.z
    ok = np.isfinite(zb) & np.isfinite(zc)
    zb, zc, t = zb[ok], zc[ok], base.t[ok]
    if zb.size < 16:
        return 0.0
    n_blocks = int(min(max(8, (t.max() - t.min()) // max(block_s, 1e-9)), zb.size // 2))
    order = np.argsort(t, kind="stable")
    ratios = np.array(
        [
            np.log(np.mean(b**2) / np.mean(c**2))
            for b, c in zip(np.array_split(zb[order], n_blocks), np.array_split(zc[order], n_blocks), strict=True)
            if b.size and np.mean(c**2) > 0 and np.mean(b**2) > 0
        ]
    )
    if ratios.size < 2:
        return 0.0
    se = float(np.std(ratios, ddof=1) / np.sqrt(ratios.size))
    return float(ratios.mean() / se) if se > 0 else (np.inf if ratios.mean() > 0 else 0.0)


__all__ = ["HeldOut", "held_out", "improvement_z"]
