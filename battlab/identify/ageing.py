"""Ageing between test dates as explicit per-file parameters: each data file's own cyclable lithium and capacity.

A cell tested over weeks ages between its tests (the Panasonic 18650PF of the shared data set loses 2.8 -> 2.3 Ah
over its campaign). One set of values for every file then explains the lost capacity by the dynamics (an
electrolyte that empties early, a diffusivity at its bound). With ``per-file ageing`` each data file gets

* ``n_Li`` [mol]: its cyclable lithium (eq. 10). Every file starts at the open-circuit voltage the reference cell
  has at the file's start SOC (``soc0 = 1``: the state the lab's full charge leaves, the same voltage on every
  date), with its own lithium: the start stoichiometries (θ⁻, θ⁺) solve U⁺(θ⁺) − U⁻(θ⁻) = V₀ and
  c H⁻ θ⁻ + c H⁺ θ⁺ = n_Li (:func:`battlab.cell.rest_stoichiometries`). Bounds: the reference cell's n_Li ±
  :data:`N_LI_SPAN`.
* ``capacity`` c [1]: the fraction of the electrode stack still active (loss of active material of both electrodes
  with the lithium it holds), a factor on the electrode area A and so on both H± = ε_s L A c_max (eq. 11). An area
  factor leaves every current density of the aged cell equal to that of the reference cell at the current I/c, so
  the reference cell's model runs at I/c; the contact resistance's drop, which does not scale with area, is
  corrected to R_c I (:meth:`battlab.identify.forward.ForwardModel.run`). The heat of that run is the reference
  cell's at I/c, 1/c times the aged cell's (the temperature rise is overestimated by up to 1/c − 1; a cell per file
  with its own area, an input of the compiled model, would not be). Bounds :data:`CAPACITY_BOUNDS`.

Both are fitted with the shared parameters (one-sided finite-difference Jacobian columns, as the start SOC where a
file's lithium fixes its start stoichiometries); their values and 95 % intervals are reported per file. The exported
cell (one cell) holds the mean of the per-file values over the dynamic data files (:func:`aged_cell`): one cell for
every date of the campaign, each file's own state kept in the fit's summary and the BPX user-defined metadata.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from battlab.cell import Cell, rest_stoichiometries
from protocols.errors import InputError

#: the per-file ageing parameters
NAMES = ("n_Li", "capacity")
#: [1] n_Li within ± this fraction of the reference cell's
N_LI_SPAN = 0.15
#: [1] bounds of the capacity factor (of the reference cell's)
CAPACITY_BOUNDS = (0.7, 1.05)


def parse_names(text: str | Sequence[str]) -> tuple[str, ...]:
    """``"n_Li,capacity"`` (or a sequence) as names; an unknown or repeated name is an :class:`InputError`."""
    items = [s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip()]
    if not items:
        raise InputError(f"--per-file-ageing: no names given; expected some of {', '.join(NAMES)}")
    for s in items:
        if s not in NAMES:
            raise InputError(f"--per-file-ageing: unknown name {s!r}; expected some of {', '.join(NAMES)}")
    if len(set(items)) != len(items):
        raise InputError(f"--per-file-ageing: a name is given twice in {','.join(items)}")
    return tuple(n for n in NAMES if n in items)


@dataclass(frozen=True)
class Ageing:
    """Which ageing parameters each data file gets, the file of each experiment (experiment name -> file label), the
    reference cell's n_Li [mol] and the start values per file (label -> name -> value; missing: the reference's)."""

    names: tuple[str, ...]
    files: Mapping[str, str]
    n_li_ref: float
    start: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def bounds(self, name: str) -> tuple[float, float]:
        if name == "n_Li":
            return (1.0 - N_LI_SPAN) * self.n_li_ref, (1.0 + N_LI_SPAN) * self.n_li_ref
        return CAPACITY_BOUNDS

    def reference(self, name: str) -> float:
        return self.n_li_ref if name == "n_Li" else 1.0

    def normalise(self, name: str, value: float) -> float:
        lo, hi = self.bounds(name)
        return (value - lo) / (hi - lo)

    def denormalise(self, name: str, x: float) -> float:
        lo, hi = self.bounds(name)
        return lo + x * (hi - lo)

    def start_value(self, label: str, name: str) -> float:
        return float(self.start.get(label, {}).get(name, self.reference(name)))

    def with_start(self, values: Mapping[str, Mapping[str, float]]) -> Ageing:
        """The same with these files' start values replaced (the others kept)."""
        start = {k: dict(v) for k, v in self.start.items()}
        for label, vals in values.items():
            start.setdefault(label, {}).update({n: float(v) for n, v in vals.items()})
        return Ageing(self.names, self.files, self.n_li_ref, start)

    def state(self, label: str, values: Mapping[str, float]) -> tuple[float, float]:
        """(n_Li [mol], capacity [1]) of a file from its fitted values (a name not fitted: the reference's)."""
        n = float(values.get("n_Li", self.start_value(label, "n_Li")))
        c = float(values.get("capacity", self.start_value(label, "capacity")))
        return n, c


def aged_cell(cell: Cell, n_li: float, capacity: float, why: str) -> Cell:
    """``cell`` with ``n_li`` [mol] of cyclable lithium and its electrode area A times ``capacity``: SOC 0 and 1 at the
    open-circuit voltages they have in ``cell`` (its stoichiometry window written, n_Li too if it has one), or where an
    electrode fills or empties first when that voltage is out of reach (more lithium than the positive electrode
    takes at V_min); ``why`` goes into the sources."""
    values: dict[str, float] = {"A": capacity * float(cell["A"])}
    if "n_Li" in cell.values:
        values["n_Li"] = n_li
    v0, v1 = float(cell.ocv(0.0)), float(cell.ocv(1.0))
    n0, p0 = rest_stoichiometries(cell, n_li, v0, capacity=capacity, clamp=True)
    n1, p1 = rest_stoichiometries(cell, n_li, v1, capacity=capacity, clamp=True)
    values.update(sto_n_0=n0, sto_n_100=n1, sto_p_0=p0, sto_p_100=p1)
    new = cell.with_values(**values)
    return Cell(new.name, new.values, {**new.sources, **dict.fromkeys(values, why)}, new.description, new.extensions)


def mean_state(per_file: Mapping[str, Mapping[str, Mapping[str, object]]], ageing: Ageing) -> dict[str, float]:
    """The mean of the per-file values (``per_file[label][name]["value"]``) for each ageing name."""
    out = {}
    for n in ageing.names:
        vals = [float(v[n]["value"]) for v in per_file.values() if n in v]  # type: ignore[arg-type]
        out[n] = float(np.mean(vals)) if vals else ageing.reference(n)
    return out


# Ageing between test dates, from the open-circuit voltage: the same cell's OCV against the charge discharged from
# full charge, measured on two dates, differs by a factor on that charge when the cell has lost capacity (lithium and
# the active material holding it, together) between them.


@dataclass(frozen=True)
class CapacityRatio:
    """How the OCV of test ``a`` against its discharged charge q [Ah] maps onto that of test ``b``:
    V_a(q) = V_b(ratio q + shift) − offset, fitted over the common charge range. ``ratio`` > 1: cell ``a`` is emptier
    at equal q, it has 1/ratio of ``b``'s capacity; ``offset`` [V]: a constant between the two (one measured after
    discharges, the other a mean of both directions: the hysteresis); ``rmse_mV`` the fit's residual; ``*_se`` the
    standard errors."""

    ratio: float
    ratio_se: float
    shift_Ah: float
    offset_V: float
    rmse_mV: float
    points: int


def rest_points(
    t: np.ndarray,
    current: np.ndarray,
    voltage: np.ndarray,
    discharged: np.ndarray | None = None,
    *,
    min_rest_s: float = 600.0,
    i_rest: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """The voltage [V] at the end of every rest of at least ``min_rest_s`` [s] that is followed by current, and the
    charge discharged since the first sample, q [Ah]: ``discharged`` (e.g. from a logged Ah column, where the log has
    gaps), else the integral of ``current`` (positive = charge, A)."""
    t, current, voltage = (np.asarray(a, float) for a in (t, current, voltage))
    if discharged is None:
        q = -np.concatenate([[0.0], np.cumsum(current[:-1] * np.diff(t))]) / 3600.0
    else:
        q = np.asarray(discharged, float) - float(discharged[0])
    rest = np.abs(current) < i_rest
    ends = np.flatnonzero(rest[:-1] & ~rest[1:])
    starts = np.flatnonzero(np.r_[True, ~rest[:-1]] & rest)
    keep = [k for k in ends if t[k] - t[starts[starts <= k][-1]] >= min_rest_s]
    return q[keep], voltage[keep]


def capacity_ratio(q_a: np.ndarray, v_a: np.ndarray, q_b: np.ndarray, v_b: np.ndarray) -> CapacityRatio:
    """Fit V_a(q) = V_b(ratio q + shift) − offset (:class:`CapacityRatio`) over the points of ``a`` inside ``b``'s
    charge range; ``b`` is a curve (sorted or not), ``a`` may be scattered rest points."""
    from scipy.optimize import least_squares

    o = np.argsort(q_b)
    qb, vb = np.asarray(q_b, float)[o], np.asarray(v_b, float)[o]
    qa, va = np.asarray(q_a, float), np.asarray(v_a, float)
    inside = (qa > qb[0]) & (qa < qb[-1])
    if inside.sum() < 4:
        raise InputError(f"capacity ratio: {int(inside.sum())} points in the common charge range; needs at least 4")
    qa, va = qa[inside], va[inside]

    def resid(p: np.ndarray) -> np.ndarray:
        return np.interp(p[0] * qa + p[1], qb, vb) - p[2] - va

    sol = least_squares(resid, [1.0, 0.0, 0.0])
    s2 = float(np.mean(sol.fun**2)) * qa.size / max(qa.size - 3, 1)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    return CapacityRatio(
        ratio=float(sol.x[0]),
        ratio_se=float(np.sqrt(cov[0, 0])),
        shift_Ah=float(sol.x[1]),
        offset_V=float(sol.x[2]),
        rmse_mV=float(1e3 * np.sqrt(np.mean(sol.fun**2))),
        points=int(qa.size),
    )


@dataclass(frozen=True)
class LinearFade:
    """Capacity relative to a reference date falling linearly with the days since it: c(d) = 1 − rate (d − d_ref).

    Calendar days, not charge throughput: the shared files log each test's own charge but not the cycling between
    tests (conditioning, capacity checks, the other tests of the campaign), so the throughput between two dates is not
    known from them, while every file's first time stamp is."""

    reference: str  # ISO date of the reference (capacity 1)
    rate_per_day: float
    rate_se: float

    def capacity(self, date: str) -> float:
        """The capacity factor on ``date`` (ISO) relative to the reference date's."""
        return 1.0 - self.rate_per_day * days_between(self.reference, date)


def days_between(a: str, b: str) -> float:
    """Days from ISO date (or date-time) ``a`` to ``b``."""
    from datetime import datetime

    return (datetime.fromisoformat(b) - datetime.fromisoformat(a)).total_seconds() / 86400.0


def fade_from(earlier: str, later: str, ratio: CapacityRatio) -> LinearFade:
    """The linear fade from the OCV comparison ``ratio`` of a test on date ``earlier`` (its ``a``) with one on
    ``later`` (its ``b``), referred to ``later``: the earlier cell had 1/ratio of the later one's capacity."""
    days = days_between(earlier, later)
    if days <= 0:
        raise InputError(f"fade: {earlier} is not before {later}")
    return LinearFade(later, (1.0 / ratio.ratio - 1.0) / days, ratio.ratio_se / ratio.ratio**2 / days)


def cell_on(cell: Cell, fade: LinearFade, date: str) -> Cell:
    """``cell`` (measured on ``fade.reference``) as it was or will be on ``date``: its capacity (electrode area and
    lithium together, so its OCV against SOC is unchanged) times ``fade.capacity(date)``."""
    c = fade.capacity(date)
    why = f"aged to {date} from {fade.reference} at {100 * fade.rate_per_day:.4f} %/day (battlab.identify.ageing)"
    return aged_cell(cell, c * cell.lithium_moles(), c, why)
