"""The fit's :class:`Experiment` (a profile, its measured voltage and weights) and logged data → experiments: split
at gaps, resample to a uniform grid, start SOC, ambient, weights.

* Segments: the data are cut where the time stamps jump by more than ``max_gap``, or by more than
  :data:`battlab.io.checks.GAP_FACTOR` × the data's own median sampling interval when that is longer (the
  Panasonic HPPC file logs only the pulses, not the discharges between them; its C/20 test is sampled every 60 s
  and has no gap); each segment is one experiment.
* Resampling to ``dt`` (default 1 s, the sampling of the Fisher information): the current is averaged over each
  interval [t_k, t_k + dt) (charge-conserving, zero-order hold), the voltage is interpolated at t_k.
* Start SOC: ``meta["soc0"]`` if logged; else from the first sample's voltage when the cell rests there
  (rest voltage ↔ OCV of the cell); else, in a log with steps (``Step Count / 1``, as the run logs have), from the
  first step that sets the state (:func:`logged_start`): the data then start after it; else an error. Later
  segments add the charge passed
  (``Net Capacity / Ah`` if logged, else ∫I dt) divided by the cell's capacity.
* Ambient: the given ``ambient``, else the mean chamber temperature, else an error (never a guess); T0: the
  surface temperature at the segment's start.
* Weights: Q from the noise model (eqs. 37–40) plus quantisation (:func:`variance_of`).
* Data and cell must match (:func:`check_cell`): voltages more than ``V_TOL`` outside the cell's window, or a rest
  voltage outside its OCV range, are an error naming the samples; more charge passed than the cell holds is a
  warning.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from battlab.cell import Cell
from battlab.io.checks import DataWarning, gap_threshold, ranges
from battlab.io.data import NET_CAPACITY, STEP, SURFACE, LoggedData
from battlab.noise import NoiseModel
from protocols.errors import InputError
from protocols.profile import Profile

#: Voltage quantisation of the tester [V]; its variance Δ²/12 is added to the noise model's Q.
QUANTUM = 1e-4


@dataclass(frozen=True, eq=False)
class Experiment:
    """One identification (or validation) experiment: the applied profile and the measured voltage.

    ``voltage`` [V] at ``profile.t``; ``variance`` Q_i [V²] (scalar or per sample); start from rest at
    ``soc0``; ``ambient`` and ``T0`` [K]; ``mask`` selects the samples that enter the fit (default all).
    ``lead_in``: the first samples only carry the cell's state into the scored part (e.g. the logged preparation
    from a full charge to the profile's start): they are simulated, never scored (the mask excludes them).
    ``sample_delay``: the tester's set-to-sample delay (:func:`logged_sample_delay`); the model changes the current
    that long before the sample that logs the change (``Settings.current_lead``).
    """

    name: str
    profile: Profile
    voltage: np.ndarray
    soc0: float
    variance: float | np.ndarray
    ambient: float = 298.15
    T0: float | None = None
    mask: np.ndarray | None = None
    truth: np.ndarray | None = None  # noise-free voltage, when known (virtual lab)
    lead_in: int = 0
    temperature: np.ndarray | None = None  # measured surface temperature [K] at ``profile.t`` (NaN: none there)
    t_variance: float = 0.0  # its noise variance [K²] (0: unknown, the temperature is not scored)
    sample_delay: float = 0.0  # [s] each sample's current took effect this long before it (0: at its time stamp)

    def __post_init__(self) -> None:
        v = np.asarray(self.voltage, float).reshape(-1)
        if v.size != self.profile.t.size:
            raise InputError(f"experiment {self.name}: {v.size} voltages for {self.profile.t.size} samples")
        if not np.isfinite(v).all():
            raise InputError(f"experiment {self.name}: voltage has NaN")
        q = np.broadcast_to(np.asarray(self.variance, float), v.shape)
        if not (np.isfinite(q).all() and (q > 0).all()):
            raise InputError(f"experiment {self.name}: the variance Q must be positive and finite")
        object.__setattr__(self, "voltage", v)
        object.__setattr__(self, "variance", q)
        m = np.ones(v.size, bool) if self.mask is None else np.asarray(self.mask, bool).reshape(-1).copy()
        if not 0 <= self.lead_in < v.size:
            raise InputError(f"experiment {self.name}: lead-in of {self.lead_in} samples for {v.size} samples")
        m[: self.lead_in] = False
        object.__setattr__(self, "mask", m)
        if self.temperature is not None:
            T = np.asarray(self.temperature, float).reshape(-1)
            if T.size != v.size:
                raise InputError(f"experiment {self.name}: {T.size} temperatures for {v.size} samples")
            object.__setattr__(self, "temperature", T)

    @property
    def has_temperature(self) -> bool:
        """Whether the surface temperature is logged and can be scored (a known noise level, finite samples)."""
        return self.temperature is not None and self.t_variance > 0 and bool(np.isfinite(self.temperature).any())

    @property
    def hours(self) -> float:
        """Duration of the scored part [h] (the lead-in left out)."""
        return (self.profile.t[-1] - self.profile.t[self.lead_in]) / 3600.0

    @property
    def scored_profile(self) -> Profile:
        """The profile after the lead-in (its time from 0, its metadata kept)."""
        if not self.lead_in:
            return self.profile
        p = self.profile
        t = p.t[self.lead_in :]
        return Profile(t - t[0], p.current[self.lead_in :], id=p.id, kind=p.kind, soc0=p.soc0, params=dict(p.params))

    @property
    def scored_voltage(self) -> np.ndarray:
        """The voltage after the lead-in [V]."""
        return self.voltage[self.lead_in :]


def variance_of(profile: Profile, noise: NoiseModel | None = None, quantum: float = QUANTUM) -> float:
    """Q [V²] of a profile: the noise model's q̂² (eqs. 37–40) plus quantisation Δ²/12."""
    return (noise or NoiseModel()).variance(profile) + quantum**2 / 12.0


def segments(data: LoggedData, max_gap: float = 60.0) -> list[slice]:
    """Index slices between time gaps: steps longer than ``max_gap`` [s] and than the data's own sampling allows
    (:func:`battlab.io.checks.gap_threshold`); segments of < 10 samples are dropped."""
    gaps = np.flatnonzero(np.diff(data.t) > gap_threshold(data.t, min_gap_s=max_gap)) + 1
    edges = np.concatenate([[0], gaps, [len(data)]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b - a >= 10]


def read_delay(t: np.ndarray, dt: float) -> float:
    """How long after a grid time [s] a log resampled every ``dt`` [s] by :func:`resample` holds the voltage with the
    bin's current applied: 0 for a log that marks its current steps (two rows within 1 % of ``dt``, the left and
    right limits, as battlab's run logs do) or reads no faster than ``dt`` / 4; else its median logging interval.
    A tester that logs at a fixed rate (a 1 Hz drive cycle logged at 10 Hz, the Panasonic NCR18650PF files) steps
    its current between two readings around the grid time, so the reading there is the left limit, the voltage of
    the bin before: paired with the bin's current, every pulse of the 25 degC US06 came one second late against the
    model (the recipe's cell: 34.6 mV RMSE; read one logging interval later, 27.9 mV)."""
    if dt <= 0 or t.size < 3:
        return 0.0
    steps = np.diff(t)
    if np.any((steps >= 0) & (steps <= 0.01 * dt)):
        return 0.0
    interval = float(np.median(steps))
    return interval if 0.0 < interval <= 0.25 * dt else 0.0


def resample(
    t: np.ndarray, current: np.ndarray, voltage: np.ndarray, dt: float, read_after: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform grid from t[0] every ``dt`` [s]: bin-averaged current (zero-order hold), interpolated voltage.

    The voltage at a grid time is the right limit, as the model's (the value with the bin's current applied): a row
    followed within 1 % of ``dt`` by another is the left limit of a step change (a tester logs the last sample of a
    step and the first of the next a millisecond apart), so it is left out of the voltage's interpolation (kept in
    the charge). Interpolating through it put the rest voltage at the grid time where a profile starts, against the
    model's loaded voltage: hundreds of mV at one sample per experiment. ``read_after`` [s]: the voltage is read
    this long after each grid time (:func:`read_delay`), and the model's right limit stands for it: what the cell
    relaxes in a 0.1 s logging interval is 0.4 mV RMS on the 25 degC US06 (the model run with its current changed
    0.1 s before each sample, ``Settings.current_lead``, against its right limits), against 35 mV of model error."""
    if dt <= 0:
        return t - t[0], current, voltage
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9))
    if n < 2:
        raise InputError(f"a segment of {t[-1] - t[0]:.3g} s is too short to resample at {dt} s")
    grid = t[0] + dt * np.arange(n + 1)
    charge = np.concatenate([[0.0], np.cumsum(current[:-1] * np.diff(t))])  # A s at each sample (ZOH)

    def q_at(x: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 1)
        return charge[k] + current[k] * (x - t[k])

    q = q_at(grid)
    i = np.empty(grid.size)
    i[:-1] = np.diff(q) / dt
    # the last grid time has no bin: the current logged there (a row within 1 % of dt after it is the same instant,
    # as for the voltage below); copying the last bin's put a square wave's final pulse against the rest voltage
    # logged a millisecond later: 566 mV at one sample, s² x 100 on a 600 s pulse train
    i[-1] = current[np.searchsorted(t, grid[-1] + 0.01 * dt, side="right") - 1]
    right = np.r_[np.diff(t) > 0.01 * dt, True]
    return grid - grid[0], i, np.interp(grid + read_after, t[right], voltage[right])


#: How far [V] logged voltages may lie outside the cell's [V_min, V_max] (sensing error, overshoot at a cut-off).
V_TOL = 0.15


def check_cell(data: LoggedData, cell: Cell) -> None:
    """Whether ``data`` can come from ``cell``: an :class:`InputError` naming the file, samples and window if the
    voltage leaves the cell's window by more than :data:`V_TOL` (another chemistry, or another cell's file); a
    :class:`DataWarning` if the charge passed exceeds the cell's capacity by more than 15 %."""
    where = data.source or data.name
    lo, hi = float(cell["V_min"]) - V_TOL, float(cell["V_max"]) + V_TOL
    bad = (data.voltage < lo) | (data.voltage > hi)
    if bad.any():
        raise InputError(
            f"{where}: voltage {float(np.min(data.voltage)):.3f}–{float(np.max(data.voltage)):.3f} V leaves cell "
            f"{cell.name!r}'s window {float(cell['V_min']):.2f}–{float(cell['V_max']):.2f} V by more than "
            f"{V_TOL} V at {ranges(bad, data.t)}: data and cell do not match"
        )
    q = np.concatenate([[0.0], np.cumsum(data.current[:-1] * np.diff(data.t))]) / 3600.0
    swing = float(q.max() - q.min())
    if swing > 1.15 * cell.capacity():
        warnings.warn(
            f"{where}: {swing:.3f} Ah passed in one direction, more than cell {cell.name!r}'s capacity "
            f"{cell.capacity():.3f} Ah: check the cell (or its capacity from an OCV test)",
            DataWarning,
            stacklevel=2,
        )


#: [V] a charge that ends this close to the cell's V_max, on a taper, leaves the cell full
FULL_V_TOL = 0.015
#: how :func:`state_steps` names a full charge (the start of its description)
FULL_CHARGE = "the charge to"
#: [s] a rest at least this long ends near equilibrium: its last voltage is the OCV
LONG_REST_S = 1800.0


def state_steps(data: LoggedData, cell: Cell, i_rest: float) -> list[tuple[int, float, str]]:
    """The steps of a log with steps (``Step Count / 1``) that set the cell's state, in order, as (the first sample
    after the step, the SOC there, what set it): a charge that ends within :data:`FULL_V_TOL` of V_max with the
    current tapered below C/20 (a CCCV or CV to V_max) leaves SOC 1; a rest (|I| ≤ ``i_rest`` [A]) of at least
    :data:`LONG_REST_S` (from its first sample to the next step's) leaves the SOC whose OCV is its last voltage.
    Only steps with data after them count."""
    steps = data.columns.get(STEP)
    if steps is None or len(data) < 2:
        return []
    edges = np.flatnonzero(np.diff(steps) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(data)]])
    v_max, taper = float(cell["V_max"]), float(cell["Q_nom"]) / 20
    lo, hi = float(cell.ocv(0.0)), float(cell.ocv(1.0))
    out = []
    for a, b in zip(starts[:-1], ends[:-1], strict=True):  # a step with data after it
        i, v = data.current[a:b], data.voltage[a:b]
        if i.max() > i_rest and abs(float(v[-1]) - v_max) <= FULL_V_TOL and 0 <= float(i[-1]) <= taper:
            out.append((int(b), 1.0, f"{FULL_CHARGE} {v_max:g} V ending at {float(data.t[b - 1]):.0f} s (SOC 1)"))
        elif np.all(np.abs(i) <= i_rest) and float(data.t[b] - data.t[a]) >= LONG_REST_S:  # until the next step
            soc = cell.soc_from_voltage(float(np.clip(v[-1], lo, hi)))
            how = f"the rest ending at {float(data.t[b - 1]):.0f} s ({float(v[-1]):.4f} V, SOC {soc:.3f})"
            out.append((int(b), soc, how))
    return out


def logged_start(data: LoggedData, cell: Cell, i_rest: float) -> tuple[int, float, str] | None:
    """The first step of a log with steps that sets the cell's state (:func:`state_steps`), or None."""
    found = state_steps(data, cell, i_rest)
    return found[0] if found else None


def _from(data: LoggedData, k: int) -> LoggedData:
    """``data`` from sample ``k`` on."""
    return LoggedData(data.name, {c: v[k:] for c, v in data.columns.items()}, data.meta, data.source)


def experiments_from_data(
    data: LoggedData,
    cell: Cell,
    *,
    dt: float = 1.0,
    noise: NoiseModel | None = None,
    soc0: float | None = None,
    max_gap: float = 60.0,
    rest_current: float | None = None,
    ambient: float | None = None,
) -> list[Experiment]:
    """The fit experiments of one logged test (one per segment between gaps); see the module docstring."""
    where = data.source or data.name
    check_cell(data, cell)
    segs = segments(data, max_gap)
    if not segs:
        raise InputError(f"{where}: no segment of at least 10 samples between gaps")
    cap = cell.capacity()
    i_rest = rest_current if rest_current is not None else 0.01 * float(cell["Q_nom"])
    start = soc0 if soc0 is not None else data.meta.get("soc0")
    if start is None and abs(data.current[segs[0].start]) > i_rest:
        found = logged_start(data, cell, i_rest)
        if found is not None:
            k, start, how = found
            data = _from(data, k)
            data.meta["start"] = f"SOC {start:.4g} after {how}"
            segs = segments(data, max_gap)
            if not segs:
                raise InputError(f"{where}: no segment of at least 10 samples after {how}")
    if start is None:
        k = segs[0].start
        if abs(data.current[k]) > i_rest:
            raise InputError(
                f"{where}: current flows at the first sample ({data.current[k]:.3g} A): give the start SOC "
                "(soc0 / --soc0), or start the log at rest"
            )
        v0, ocv_lo, ocv_hi = float(data.voltage[k]), float(cell.ocv(0.0)), float(cell.ocv(1.0))
        if not ocv_lo - 0.05 <= v0 <= ocv_hi + 0.05:
            raise InputError(
                f"{where}: the rest voltage {v0:.3f} V at sample {k} is outside cell {cell.name!r}'s "
                f"OCV range {ocv_lo:.3f}–{ocv_hi:.3f} V: data and cell do not match (or give --soc0)"
            )
        start = cell.soc_from_voltage(float(np.clip(v0, ocv_lo, ocv_hi)))
    start = float(start)
    ah = data.columns.get(NET_CAPACITY)
    if ah is None:
        ah = np.concatenate([[0.0], np.cumsum(data.current[:-1] * np.diff(data.t))]) / 3600.0
    amb = float(ambient) if ambient is not None else data.ambient_K()
    if not 200.0 < amb < 400.0:
        raise InputError(f"{where}: ambient {amb} K is not a temperature in kelvin (200–400 K)")
    surf = data.temperature_K(SURFACE)
    delay = logged_sample_delay(data)
    out = []
    for n, sl in enumerate(segs, start=1):
        k0 = sl.start
        soc = float(np.clip(start + (ah[k0] - ah[segs[0].start]) / cap, 0.0, 1.0))
        lag = read_delay(data.t[sl], dt)
        t, i, v = resample(data.t[sl], data.current[sl], data.voltage[sl], dt, lag)
        name = data.name if len(segs) == 1 else f"{data.name}#{n}"
        prof = Profile(t, i, id=name, soc0=soc)
        T0 = float(surf[k0]) if surf is not None and np.isfinite(surf[k0]) else None
        T, t_var = None, 0.0
        if surf is not None and np.isfinite(surf[sl]).sum() >= 10:
            ok = np.isfinite(surf[sl])
            T = np.interp(t + data.t[sl][0], data.t[sl][ok], surf[sl][ok])
            t_var = temperature_noise_variance(surf[sl][ok])
        out.append(
            Experiment(
                name,
                prof,
                v,
                soc,
                variance_of(prof, noise),
                amb,
                T0,
                temperature=T,
                t_variance=t_var,
                sample_delay=delay,
            )
        )
    return out


def logged_sample_delay(data: LoggedData) -> float:
    """The mean time [s] from a change of the current to the sample that logs it, as battlab's run engine records
    it in a run log (``meta["final"]["stats"]["mean_set_to_sample_s"]``: the instrument's time stamps of the
    setting and of the reading); 0 for a file that does not say. A host-paced tester sets the current, then
    measures: on the virtual tester 10 ms, whose relaxation after a current step is 0.1 mV per ampere of the step
    on nca18650-true, a third of its noise, and correlated from sample to sample."""
    final = data.meta.get("final")
    stats = final.get("stats") if isinstance(final, dict) else None
    value = stats.get("mean_set_to_sample_s") if isinstance(stats, dict) else None
    try:
        d = float(value) if value is not None else 0.0
    except (TypeError, ValueError):
        return 0.0
    return d if 0.0 < d < 1e3 else 0.0


#: the smallest temperature noise assumed [K]: a logger's resolution below it is not believed
T_NOISE_FLOOR_K = 0.01


def temperature_noise_variance(T: np.ndarray) -> float:
    """The noise variance [K²] of a logged temperature, from its sample-to-sample changes (a temperature moves
    slowly: what jumps between samples is noise): the robust spread (MAD) of the first differences over √2, or a
    logger's quantisation step Δ as Δ²/12 when most changes are zero; at least :data:`T_NOISE_FLOOR_K`²."""
    d = np.diff(np.asarray(T, float))
    d = d[np.isfinite(d)]
    if d.size < 5:
        return T_NOISE_FLOOR_K**2
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    nonzero = np.abs(d[d != 0.0])
    if sigma == 0.0 and nonzero.size:
        sigma = float(np.min(nonzero)) / np.sqrt(12.0)
    return max(sigma, T_NOISE_FLOOR_K) ** 2
