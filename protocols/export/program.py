"""What every exporter works from: protocol steps, with profiles cut into timed holds and loops.

A profile becomes *holds* (constant current for a fixed time: its zero-order-hold segments, consecutive equal
currents merged) and, where the same run of holds repeats back to back (pulse trains, tiled sine periods,
repeated drive cycles), a :class:`Repeat` of that run. Formats with loops (Arbin, BioLogic, Neware) write a
loop; the others write the expanded holds.

The *canonical* form (:func:`canonical`) is what a re-import is compared against: a flat list in which every
step that is fully described by a duration and a current (rests and CC steps ending on time alone, and all
profile holds) is a :class:`Hold`, consecutive holds with equal current are merged, and all other steps stay
as they are.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from protocols.errors import InputError
from protocols.profile import Profile
from protocols.protocol import (
    CCCV,
    ConstantCurrent,
    ConstantVoltage,
    EndCondition,
    ProfileStep,
    Protocol,
    Quantity,
    Rest,
    Step,
)


@dataclass(frozen=True)
class Hold:
    """Constant current [A] (0 = rest) for ``duration`` [s]."""

    duration: float
    current: float


@dataclass(frozen=True)
class Repeat:
    """``body`` played ``count`` times back to back."""

    body: tuple[Hold, ...]
    count: int

    @property
    def duration(self) -> float:
        """Total duration [s]."""
        return self.count * sum(h.duration for h in self.body)


Item = Hold | Repeat
Canonical = Hold | Rest | ConstantCurrent | ConstantVoltage | CCCV


def compress(durations: np.ndarray, currents: np.ndarray, *, max_period: int | None = None) -> tuple[Item, ...]:
    """Cut a run of holds into holds and repeats (greedy, left to right, exact equality).

    At each position the period p (at most ``max_period`` holds, default half the run) whose back-to-back
    repetition covers the most holds is taken when it saves steps (p + 1 steps instead of p * count); ties
    go to the shorter period.
    """
    d = np.asarray(durations, dtype=float)
    c = np.asarray(currents, dtype=float)
    n = d.size
    if n == 0:
        return ()
    _, keys = np.unique(np.column_stack([d, c]), axis=0, return_inverse=True)
    keys = keys.reshape(-1)
    pmax = n // 2 if max_period is None else min(max_period, n // 2)
    idx = np.arange(n + 1)
    periods: list[int] = []
    runs: list[np.ndarray] = []
    for p in range(1, pmax + 1):
        eq = np.zeros(n + 1, dtype=bool)
        eq[: n - p] = keys[: n - p] == keys[p:]
        if np.count_nonzero(eq) < p:  # no stretch can repeat twice with this period
            continue
        false_at = np.where(~eq, idx, n + 1)
        run = np.minimum.accumulate(false_at[::-1])[::-1] - idx  # consecutive matches from each position
        if run.max() >= p:
            periods.append(p)
            runs.append(run)
    per = np.asarray(periods, dtype=np.int64)
    run_m = np.vstack(runs) if runs else np.zeros((0, n + 1), dtype=np.int64)
    items: list[Item] = []
    i = 0
    while i < n:
        if per.size:
            reps = run_m[:, i] // per + 1
            gain = np.where(reps >= 2, reps * per - (per + 1), -1)
            k = int(np.argmax(gain))
            if gain[k] > 0:
                p, r = int(per[k]), int(reps[k])
                items.append(Repeat(tuple(Hold(float(d[j]), float(c[j])) for j in range(i, i + p)), r))
                i += p * r
                continue
        items.append(Hold(float(d[i]), float(c[i])))
        i += 1
    return tuple(items)


def profile_items(
    profile: Profile,
    *,
    loops: bool = True,
    max_period: int | None = None,
    current_quantum: float | None = None,
) -> tuple[Item, ...]:
    """A profile as holds (and repeats, with ``loops``).

    With ``current_quantum`` [A] currents are first rounded to that resolution (as the file will hold
    them; a current that rounds to zero becomes a rest) and neighbours made equal by the rounding merged.
    """
    d, c = profile.segments()
    if current_quantum:
        c = np.round(c / current_quantum) * current_quantum + 0.0
        keep = np.concatenate([[True], np.diff(c) != 0])
        idx = np.cumsum(keep) - 1
        d = np.bincount(idx, weights=d)
        c = c[keep]
    if not loops:
        return tuple(Hold(float(x), float(y)) for x, y in zip(d, c, strict=True))
    return compress(d, c, max_period=max_period)


def expand(items: Iterable[Item]) -> list[Hold]:
    """Holds of ``items`` with repeats played out."""
    out: list[Hold] = []
    for it in items:
        if isinstance(it, Repeat):
            out.extend(it.body * it.count)
        else:
            out.append(it)
    return out


def count_steps(items: Sequence[Item]) -> int:
    """Steps a looping format needs: one per hold, one per repeat body hold, one per loop."""
    return sum(len(it.body) + 1 if isinstance(it, Repeat) else 1 for it in items)


def time_only(step: Step) -> float | None:
    """Duration [s] of a rest or CC step that ends on time alone (else None)."""
    if isinstance(step, Rest | ConstantCurrent) and len(step.ends) == 1:
        e = step.ends[0]
        if e.quantity is Quantity.TIME:
            return e.value
    return None


def merge_holds(seq: Iterable[Canonical]) -> list[Canonical]:
    """Merge consecutive holds with bit-identical current; drop zero-length holds."""
    out: list[Canonical] = []
    for x in seq:
        if isinstance(x, Hold):
            if x.duration <= 0:
                continue
            if out and isinstance(out[-1], Hold) and out[-1].current == x.current:
                out[-1] = Hold(out[-1].duration + x.duration, x.current)
                continue
        out.append(x)
    return out


def canonical(protocol: Protocol) -> list[Canonical]:
    """The canonical flat form of ``protocol`` (see the module docstring)."""
    seq: list[Canonical] = []
    for s in protocol.steps:
        if isinstance(s, ProfileStep):
            seq.extend(expand(profile_items(s.profile, loops=False)))
            continue
        d = time_only(s)
        if d is not None:
            seq.append(Hold(d, s.current if isinstance(s, ConstantCurrent) else 0.0))
        else:
            seq.append(s)
    return merge_holds(seq)


def holds_profile(items: Sequence[Canonical], **meta: object) -> Profile:
    """Profile made of the holds of a canonical list (refuses other steps)."""
    holds = []
    for k, x in enumerate(items, start=1):
        if not isinstance(x, Hold):
            raise InputError(f"item {k} ({type(x).__name__}) is not a timed hold; it has no fixed current")
        holds.append(x)
    if not holds:
        raise InputError("no timed holds to make a profile of")
    return Profile.from_segments([h.duration for h in holds], [h.current for h in holds], **meta)  # type: ignore[arg-type]


def _merge_close(seq: Sequence[Canonical], current_tol: float) -> list[Canonical]:
    """Merge neighbouring holds whose currents agree within ``current_tol`` (rounding in a file can make
    two distinct neighbouring samples equal, and the re-import then merges them)."""
    out: list[Canonical] = []
    for x in seq:
        last = out[-1] if out else None
        if isinstance(x, Hold) and isinstance(last, Hold) and abs(last.current - x.current) <= current_tol:
            out[-1] = Hold(last.duration + x.duration, last.current)
        else:
            out.append(x)
    return out


def _close(a: float, b: float, tol: float) -> bool:
    return abs(a - b) <= tol + 1e-12 * max(abs(a), abs(b))


def _ends_key(ends: Sequence[EndCondition]) -> list[tuple[str, str, float]]:
    return sorted((e.quantity.value, e.op.value, e.value) for e in ends)


def difference(
    a: Sequence[Canonical],
    b: Sequence[Canonical],
    *,
    time_tol: float,
    current_tol: float,
    value_tol: float = 1e-6,
) -> str | None:
    """First difference between two canonical lists beyond the tolerances, or None if equivalent.

    ``time_tol`` [s] and ``current_tol`` [A] bound holds (neighbouring holds within ``current_tol`` of each
    other are merged first); ``value_tol`` bounds voltages, currents and end values of other steps (relative
    to their magnitude for end values).
    """
    a, b = _merge_close(a, current_tol), _merge_close(b, current_tol)
    if len(a) != len(b):
        return f"{len(a)} items vs {len(b)} items"
    for k, (x, y) in enumerate(zip(a, b, strict=True), start=1):
        if type(x) is not type(y):
            return f"item {k}: {type(x).__name__} vs {type(y).__name__}"
        if isinstance(x, Hold):
            assert isinstance(y, Hold)
            if not _close(x.duration, y.duration, time_tol) or not _close(x.current, y.current, current_tol):
                return f"item {k}: hold {x.duration:g} s at {x.current:g} A vs {y.duration:g} s at {y.current:g} A"
            continue
        for name in ("current", "voltage"):
            u, v = getattr(x, name, None), getattr(y, name, None)
            if (u is None) != (v is None) or (u is not None and not _close(u, v, value_tol)):
                return f"item {k} ({type(x).__name__}): {name} {u} vs {v}"
        if getattr(x, "direction", None) != getattr(y, "direction", None):
            return f"item {k}: direction {x.direction} vs {y.direction}"  # type: ignore[union-attr]
        ea, eb = _ends_key(x.ends), _ends_key(y.ends)
        if len(ea) != len(eb) or any(
            p[:2] != q[:2] or not math.isclose(p[2], q[2], rel_tol=value_tol, abs_tol=value_tol)
            for p, q in zip(ea, eb, strict=True)
        ):
            return f"item {k} ({type(x).__name__}): ends {ea} vs {eb}"
    return None


def split_cccv(protocol: Protocol) -> Protocol:
    """``protocol`` with every CCCV step written as a CC step to the voltage followed by a CV step there.

    For formats without a combined step (BioLogic Modulo Bat, PyBaMM): the CCCV's own ends (time, current,
    capacity) go to the CV part, so they count from the start of the constant-voltage phase.
    """
    from protocols.directions import Direction
    from protocols.protocol import voltage_above, voltage_below

    steps: list[Step] = []
    for s in protocol.steps:
        if isinstance(s, CCCV):
            charge = s.current > 0
            stop = voltage_above(s.voltage) if charge else voltage_below(s.voltage)
            steps.append(ConstantCurrent(s.current, (stop,), s.label))
            direction = Direction.CHARGE if charge else Direction.DISCHARGE
            steps.append(ConstantVoltage(s.voltage, s.ends, direction, s.label))
        else:
            steps.append(s)
    return Protocol(protocol.name, tuple(steps), protocol.limits, protocol.capacity_ah, protocol.description)
