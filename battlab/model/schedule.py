"""The step schedule: steps end at every current change (and, unless they may cross them, at every sample); sizes
restart small where the current jumps and grow geometrically up to ``dt_max``. Step sizes depend on the profile and
the settings only, never on θ̄."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from battlab.model.state import Settings

# ---------------------------------------------------------------------------------------------------------
# the step schedule


@dataclass(frozen=True)
class Schedule:
    """Steps (h [s], ω, I_dis [A], end time t_end [s] from t_0) and, per sample k ≥ 1, the index of the step that
    ends at t_k (aligned schedules) or contains it (steps across samples)."""

    h: np.ndarray
    w: np.ndarray
    current: np.ndarray
    sample_step: np.ndarray
    t_end: np.ndarray


#: a change of the current smaller than this × 1C keeps its time stamp under ``Settings.current_lead``: a logged
#: current's noise (0.2 mA on the virtual tester) is no setting of it, and a lead step at every sample of a rest would
#: double the steps for nothing (moving 3 mA by 10 ms changes the voltage by 0.3 µV)
LEAD_MIN_C = 1e-3


def next_step(remaining: float, h_allowed: float) -> float:
    """The next step [s] in what remains of a sample interval: all of it within 1.2 h_allowed, half of it within
    2 h_allowed, else h_allowed (so no sliver step ends an interval)."""
    if remaining <= 1.2 * h_allowed:
        return remaining
    if remaining <= 2.0 * h_allowed:
        return remaining / 2.0
    return h_allowed


def split_step(h: np.ndarray, w: np.ndarray, cur: np.ndarray, pos: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replace the failed step ``pos`` by h/8, h/8, h/4, h/2 (restarting with backward Euler); the step after
    keeps BDF2 only if its step ratio stays ≤ 2.4 (zero-stable), else it restarts too."""
    hb = h[pos]
    parts = np.array([hb / 8, hb / 8, hb / 4, hb / 2])
    h = np.concatenate([h[:pos], parts, h[pos + 1 :]])
    w = np.concatenate([w[:pos], [0.0, 1.0, 2.0, 2.0], w[pos + 1 :]])
    cur = np.concatenate([cur[:pos], np.repeat(cur[pos], 4), cur[pos + 1 :]])
    if pos + 4 < w.size and w[pos + 4] != 0.0:
        ratio = h[pos + 4] / parts[-1]
        w[pos + 4] = ratio if ratio <= 2.4 else 0.0
    return h, w, cur


def split_ends(t_end: np.ndarray, h: np.ndarray, pos: int) -> np.ndarray:
    """The end times after :func:`split_step` at ``pos`` (``h``: the step sizes before the split); the last part
    ends exactly where the failed step did."""
    start = t_end[pos] - h[pos]
    parts = start + h[pos] * np.array([0.125, 0.25, 0.5])
    return np.concatenate([t_end[:pos], parts, t_end[pos:]])


def schedule(t: np.ndarray, I_dis: np.ndarray, i_1c: float, s: Settings) -> Schedule:
    """The step plan of a profile (zero-order hold: a step never straddles a change of the current)."""
    if s.across_samples:
        if s.current_lead:
            raise ValueError("Settings.current_lead needs steps aligned with the samples (across_samples=False)")
        return _across_samples(t, I_dis, i_1c, s)
    return _aligned(t, I_dis, i_1c, s)


def _restarts(I_dis: np.ndarray, i_1c: float, s: Settings) -> np.ndarray:
    """Per sample k: whether the current that starts at t_k restarts the scheme (k = 0 always)."""
    jump = np.abs(np.diff(I_dis)) > max(s.refine_rate * i_1c, 1e-12 * i_1c)
    return np.concatenate([[True], jump])


def _across_samples(t: np.ndarray, I_dis: np.ndarray, i_1c: float, s: Settings) -> Schedule:
    """Steps that end only where the current changes (and at the last sample); samples in between lie inside
    steps."""
    restart = _restarts(I_dis, i_1c, s)
    n = len(t) - 1
    change = np.flatnonzero(I_dis[1:n] != I_dis[: n - 1]) + 1  # samples where the current changes
    bounds = np.concatenate([[0], change, [n]])
    hs: list[float] = []
    ws: list[float] = []
    cs: list[float] = []
    ends: list[float] = []
    h_allowed = s.dt_first
    h_prev = 0.0
    t0 = float(t[0])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        first = bool(restart[a])
        if first:
            h_allowed = s.dt_first
        t_a, t_b = float(t[a]) - t0, float(t[b]) - t0
        done = 0.0
        remaining = t_b - t_a
        while remaining > 1e-12 * max(1.0, t_b):
            h = next_step(remaining, h_allowed)
            hs.append(h)
            ws.append(0.0 if first or h_prev == 0.0 else h / h_prev)
            cs.append(float(I_dis[a]))
            first = False
            remaining -= h
            done += h
            ends.append(t_a + done)
            h_prev = h
            h_allowed = min(h * s.growth, s.dt_max)
        if ends:
            ends[-1] = t_b  # exactly at the change, where the right limit is taken
    t_end = np.array(ends)
    # the step containing each sample k >= 1: the first whose end is at or after t_k
    tol = 1e-9 * np.maximum(1.0, np.abs(t[1:] - t0))
    sample_step = np.searchsorted(t_end, t[1:] - t0 - tol, side="left")
    return Schedule(np.array(hs), np.array(ws), np.array(cs), sample_step.astype(int), t_end)


def _aligned(t: np.ndarray, I_dis: np.ndarray, i_1c: float, s: Settings) -> Schedule:
    """Steps aligned with every sample; with ``s.current_lead`` a change of the current (above :data:`LEAD_MIN_C`)
    takes effect that long before the sample that carries it: the interval before it (if at least twice as long) ends
    with a backward-Euler step of ``current_lead`` at the new current, from which the steps grow on as after any
    restart (a 10 ms first step is also the more accurate start: 0.003 mV RMS from a 5 ms solution on library profile
    541, against 0.04 mV for a 0.15 s one)."""
    hs: list[float] = []
    ws: list[float] = []
    cs: list[float] = []
    ends: list[int] = []
    t_end: list[float] = []
    h_allowed = s.dt_first
    h_prev = 0.0
    t0 = float(t[0])
    lead = float(s.current_lead)
    if not 0.0 <= lead < float("inf"):
        raise ValueError(f"Settings.current_lead must be a finite time >= 0 s, got {lead}")
    led = False  # the interval before ended with a lead step (its steps go on growing from it)
    for k in range(len(t) - 1):
        jump = k == 0 or abs(I_dis[k] - I_dis[k - 1]) > max(s.refine_rate * i_1c, 1e-12 * i_1c)
        restart = jump and not led  # after a lead step its BDF2 history continues
        if restart:
            h_allowed = s.dt_first
        span = float(t[k + 1] - t[k])
        led = lead > 0.0 and abs(I_dis[k + 1] - I_dis[k]) > LEAD_MIN_C * i_1c and lead <= 0.5 * span
        remaining = span - lead if led else span
        done = 0.0
        while remaining > 1e-12 * max(1.0, float(t[k + 1])):
            h = next_step(remaining, h_allowed)
            w = 0.0 if restart or h_prev == 0.0 else h / h_prev
            hs.append(h)
            ws.append(w)
            cs.append(float(I_dis[k]))
            restart = False
            remaining -= h
            done += h
            t_end.append(float(t[k]) - t0 + done)
            h_prev = h
            h_allowed = min(h * s.growth, s.dt_max)
        t_end[-1] = float(t[k + 1]) - t0 - (lead if led else 0.0)
        if led:  # the next sample's current, for the last ``lead`` seconds before it
            hs.append(lead)
            ws.append(0.0)
            cs.append(float(I_dis[k + 1]))
            t_end.append(float(t[k + 1]) - t0)
            h_prev = lead
            h_allowed = min(lead * s.growth, s.dt_max)
        ends.append(len(hs) - 1)
    return Schedule(np.array(hs), np.array(ws), np.array(cs), np.array(ends, dtype=int), np.array(t_end))
