"""The weighted least-squares problem of eq. 41: residuals r = (ŷ − y)/√Q and their Jacobian from the model's exact
sensitivities, the start SOCs' columns included (a direction of the start state in the same solves), with one-sided
difference columns for per-file ageing (and for the start SOC where a file's lithium fixes the start stoichiometries
or the CasADi fallback runs), cached per θ̄.
A simulation that stops early at a voltage limit holds its last voltage for the missing samples (zero Jacobian rows).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from battlab import parameters
from battlab.cell import rest_stoichiometries
from battlab.identify.ageing import Ageing
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from protocols.errors import InputError


class Problem:
    """Residuals and Jacobian of eq. 41 for a set of experiments and fitted names, cached per θ̄."""

    def __init__(
        self,
        fm: ForwardModel,
        experiments: Sequence[Experiment],
        names: Sequence[str],
        theta_full: np.ndarray,
        soc_span: float = 0.0,
        pool: ThreadPoolExecutor | None = None,
        ageing: Ageing | None = None,
        temperature: bool = False,
    ) -> None:
        self.fm = fm
        #: also score the logged surface temperature (rows (T̂ − T)/σ_T of the experiments that log it)
        self.temperature = bool(temperature)
        self.exps = list(experiments)
        self.names = tuple(names)
        order = getattr(fm, "names", parameters.NAMES)  # θ̄'s order: the 18, then the cell's extensions' KEY.NAME
        self.idx = [order.index(n) for n in self.names]
        self.base = np.asarray(theta_full, float).copy()
        self.soc_span = float(soc_span)  # > 0: one start-SOC nuisance per experiment, soc0 ± soc_span
        self.n_nuis = len(self.exps) if self.soc_span > 0 else 0
        # per-file ageing: each file (label) of the experiments gets the ageing names' columns after the nuisances
        self.ageing = ageing
        self.files: list[str] = []
        self.file_of: list[int] = []
        if ageing is not None:
            for e in self.exps:
                label = ageing.files.get(e.name, e.name)
                if label not in self.files:
                    self.files.append(label)
                self.file_of.append(self.files.index(label))
        self.n_age = len(self.files) * len(ageing.names) if ageing is not None else 0
        self._cache: dict[bytes, tuple[np.ndarray, np.ndarray, list[np.ndarray]]] = {}  # the last two points
        self.n_sim = 0  # simulations of all experiments (every evaluation not found in the cache)
        self.pool = pool
        #: the fitted parameters' bounds in θ̄ (:func:`battlab.identify.fit.search_box`), then [0, 1] for the
        #: nuisances
        self.lower = np.zeros(len(self.names))
        self.upper = np.ones(len(self.names))
        #: called after every simulation of all experiments with (simulations so far, cost ½‖r‖²)
        self.on_evaluation: Callable[[int, float], None] | None = None
        #: the lowest-cost point evaluated so far and its cost (kept apart from the cache: never re-simulated)
        self.best_x: np.ndarray | None = None
        self.best_cost = float("inf")
        self._best: tuple[np.ndarray, np.ndarray, list[np.ndarray]] | None = None

    def full(self, x: np.ndarray) -> np.ndarray:
        th = self.base.copy()
        th[self.idx] = x
        return th

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        key = np.asarray(x, float).tobytes()
        if key in self._cache:
            return self._cache[key]
        if self._best is not None and self.best_x is not None and key == self.best_x.tobytes():
            return self._best
        x = np.asarray(x, float)
        th = self.full(x[: len(self.names)])
        idx = range(len(self.exps))
        parts = (
            list(self.pool.map(self._one, idx, [th] * len(idx), [x] * len(idx)))
            if self.pool
            else [self._one(i, th, x) for i in idx]
        )
        rs, js, preds = (list(z) for z in zip(*parts, strict=True))
        self.n_sim += 1
        if len(self._cache) >= 2:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = (np.concatenate(rs), np.vstack(js), preds)
        r = self._cache[key][0]
        cost = 0.5 * float(r @ r)
        if cost < self.best_cost:
            self.best_x, self.best_cost, self._best = x.copy(), cost, self._cache[key]
        if self.on_evaluation is not None:
            self.on_evaluation(self.n_sim, cost)
        return self._cache[key]

    def _one(self, i: int, th: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weighted residuals, Jacobian rows and voltage prediction of experiment i (with the temperature's rows
        after the voltage's when it is scored)."""
        e = self.exps[i]
        p = len(self.names)
        soc0 = self.soc_of(i, x)
        use_T = self.temperature and e.has_temperature
        pred, S, predT, ST, dsoc = self._run(th, i, soc0, True, x, use_T, soc_column=self.n_nuis > 0)
        w = 1.0 / np.sqrt(e.variance)
        m = e.mask
        cols, colsT = [S], [ST]

        def fd(soc: float, xh: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray | None]:
            p2, _, p2T, _, _ = self._run(th, i, soc, False, xh, use_T)
            return (p2 - pred) / h, None if p2T is None or predT is None else (p2T - predT) / h

        if self.n_nuis:  # dV/du: exact where the model gives it (u moves the SOC by 2 soc_span per unit), else
            # a one-sided difference
            if dsoc is not None:
                dv, dT = 2 * self.soc_span * dsoc[0], None if dsoc[1] is None else 2 * self.soc_span * dsoc[1]
            else:
                h = 1e-3 if x[p + i] < 0.5 else -1e-3
                dv, dT = fd(soc0 + 2 * self.soc_span * h, x, h)
            col, colT = np.zeros((e.voltage.size, self.n_nuis)), np.zeros((e.voltage.size, self.n_nuis))
            col[:, i] = dv
            if dT is not None:
                colT[:, i] = dT
            cols.append(col)
            colsT.append(colT)
        if self.n_age:  # the file's ageing columns, one-sided differences as the start SOC's
            col, colT = np.zeros((e.voltage.size, self.n_age)), np.zeros((e.voltage.size, self.n_age))
            for j in self.age_columns(i):
                h = 1e-3 if x[j] < 0.5 else -1e-3
                xh = x.copy()
                xh[j] += h
                dv, dT = fd(soc0, xh, h)
                col[:, j - p - self.n_nuis] = dv
                if dT is not None:
                    colT[:, j - p - self.n_nuis] = dT
            cols.append(col)
            colsT.append(colT)
        S = np.hstack(cols) if len(cols) > 1 else S
        r, J = ((pred - e.voltage) * w)[m], (S * w[:, None])[m]
        if use_T and predT is not None and ST is not None:
            assert e.temperature is not None
            mT = m & np.isfinite(e.temperature)
            wT = 1.0 / np.sqrt(e.t_variance)
            ST = np.hstack(colsT) if len(colsT) > 1 else ST
            r = np.concatenate([r, ((predT - e.temperature) * wT)[mT]])
            J = np.vstack([J, (ST * wT)[mT]])
        return r, J, pred

    def age_columns(self, i: int) -> list[int]:
        """The positions in x of experiment i's file's ageing parameters."""
        if not self.n_age or self.ageing is None:
            return []
        k = len(self.ageing.names)
        first = len(self.names) + self.n_nuis + self.file_of[i] * k
        return list(range(first, first + k))

    def age_values(self, g: int, x: np.ndarray) -> dict[str, float]:
        """File g's ageing values (physical units) at x."""
        assert self.ageing is not None
        k = len(self.ageing.names)
        first = len(self.names) + self.n_nuis + g * k
        return {n: self.ageing.denormalise(n, float(x[first + j])) for j, n in enumerate(self.ageing.names)}

    def age_x0(self) -> np.ndarray:
        """The ageing parameters' start (normalised), file by file."""
        if self.ageing is None:
            return np.zeros(0)
        a = self.ageing
        return np.array([a.normalise(n, a.start_value(f, n)) for f in self.files for n in a.names])

    def soc_x0(self, start: Mapping[str, float]) -> np.ndarray:
        """The start-SOC nuisances' start (normalised, 0.5: soc0): at ``start`` (name → SOC) where given, inside the
        span."""
        if not self.n_nuis:
            return np.zeros(0)
        w = 2.0 * self.soc_span
        return np.array([np.clip(0.5 + (start.get(e.name, e.soc0) - e.soc0) / w, 1e-6, 1.0 - 1e-6) for e in self.exps])

    def soc_of(self, i: int, x: np.ndarray) -> float:
        e = self.exps[i]
        if not self.n_nuis:
            return e.soc0
        return float(np.clip(e.soc0 + 2 * self.soc_span * (x[len(self.names) + i] - 0.5), 0.0, 1.0))

    def _run(
        self,
        th: np.ndarray,
        i: int,
        soc0: float,
        sens: bool,
        x: np.ndarray,
        temperature: bool = False,
        soc_column: bool = False,
    ) -> tuple[
        np.ndarray,
        np.ndarray,
        np.ndarray | None,
        np.ndarray | None,
        tuple[np.ndarray, np.ndarray | None] | None,
    ]:
        """Voltage prediction and sensitivities of experiment i at θ (full) with the ageing values of x, (with
        ``temperature``) the surface temperature's [K] and its sensitivities, and (with ``soc_column``, where the
        model gives them exactly) dV/d(start SOC) and dT/d(start SOC) (None otherwise)."""
        e = self.exps[i]
        n = e.voltage.size
        start, capacity = None, 1.0
        if self.n_age and self.ageing is not None:
            g = self.file_of[i]
            label = self.files[g]
            n_li, capacity = self.ageing.state(label, self.age_values(g, x))
            try:
                start = rest_stoichiometries(self.fm.cell, n_li, float(self.fm.cell.ocv(soc0)), capacity=capacity)
            except InputError:  # no such state: a large but finite residual, as for nothing simulated
                zT = (
                    (np.full(n, float(e.ambient) + 50.0), np.zeros((n, len(self.names))))
                    if temperature
                    else (None, None)
                )
                return np.full(n, e.voltage[0] + 1.0), np.zeros((n, len(self.names))), *zT, None
        out = self.fm.run(
            th,
            e.profile,
            soc0,
            ambient=e.ambient,
            T0=e.T0,
            sensitivities=self.names if sens else (),
            start=start,
            capacity=capacity,
            sample_delay=e.sample_delay,
            soc_sensitivity=soc_column,
        )
        pred = np.empty(n)
        S = np.zeros((n, len(self.names)))
        k = out.voltage.size
        if k:
            pred[:k] = out.voltage
            if sens:
                S[:k] = out.sensitivities
            pred[k:] = out.voltage[-1]
        else:
            pred[:] = e.voltage[0] + 1.0  # nothing simulated: a large but finite residual
        # rows after an early end are held values: zero, as the θ̄ columns'
        dsoc = None
        if out.dsoc is not None:
            dsoc = (_zero_after(out.dsoc, n), _zero_after(out.dsoc_T, n) if temperature else None)
        if not temperature:
            return pred, S, None, None, dsoc
        predT = np.full(n, float(e.ambient) + 50.0)  # nothing simulated: a large but finite residual
        ST = np.zeros((n, len(self.names)))
        if k and out.T_surface is not None:
            predT[:k] = out.T_surface
            predT[k:] = out.T_surface[-1]
            if sens and out.dT is not None:
                ST[:k] = out.dT
        return pred, S, predT, ST, dsoc


def _zero_after(a: np.ndarray | None, n: int) -> np.ndarray | None:
    """``a`` padded with zeros to ``n`` rows (None stays None)."""
    if a is None:
        return None
    out = np.zeros(n)
    out[: a.size] = a
    return out


def rmse_mV(exps: Sequence[Experiment], preds: list[np.ndarray]) -> dict[str, float]:
    return {
        e.name: float(1e3 * np.sqrt(np.mean((p - e.voltage)[e.mask] ** 2))) for e, p in zip(exps, preds, strict=True)
    }


def residual_autocorrelation(exps: Sequence[Experiment], preds: list[np.ndarray]) -> tuple[float, int]:
    """Lag-1 autocorrelation of the weighted residual, pooled over the experiments (pairs of neighbouring samples
    that are both scored), and the number of pairs. White noise gives 0 ± 1/√n; a residual the model cannot follow
    (model error the fit absorbed into its parameters) is correlated from sample to sample, whatever s² and the noise
    model say."""
    num = den = 0.0
    n = 0
    for e, p in zip(exps, preds, strict=True):
        w = (p - e.voltage) / np.sqrt(e.variance)
        pair = e.mask[:-1] & e.mask[1:]
        num += float(w[:-1][pair] @ w[1:][pair])
        den += float(w[e.mask] @ w[e.mask])
        n += int(pair.sum())
    return (num / den if den > 0 and n > 0 else float("nan")), n


def abs_errors_mV(exps: Sequence[Experiment], preds: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([1e3 * np.abs(p - e.voltage)[e.mask] for e, p in zip(exps, preds, strict=True)])
