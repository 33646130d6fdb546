"""The step schedule: steps aligned with every current change and sample, sizes limited where the current jumps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from battlab.model.state import Settings

# ---------------------------------------------------------------------------------------------------------
# the step schedule


@dataclass(frozen=True)
class Schedule:
    """Steps (h [s], ω, I_dis [A]) and, per sample k ≥ 1, the index of the step that ends at t_k."""

    h: np.ndarray
    w: np.ndarray
    current: np.ndarray
    sample_step: np.ndarray


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


def schedule(t: np.ndarray, I_dis: np.ndarray, i_1c: float, s: Settings) -> Schedule:
    """Steps aligned with every sample, so a current step is never straddled (zero-order hold)."""
    hs: list[float] = []
    ws: list[float] = []
    cs: list[float] = []
    ends: list[int] = []
    h_allowed = s.dt_first
    h_prev = 0.0
    for k in range(len(t) - 1):
        restart = k == 0 or abs(I_dis[k] - I_dis[k - 1]) > max(s.refine_rate * i_1c, 1e-12 * i_1c)
        if restart:
            h_allowed = s.dt_first
        remaining = float(t[k + 1] - t[k])
        while remaining > 1e-12 * max(1.0, float(t[k + 1])):
            h = next_step(remaining, h_allowed)
            w = 0.0 if restart or h_prev == 0.0 else h / h_prev
            hs.append(h)
            ws.append(w)
            cs.append(float(I_dis[k]))
            restart = False
            remaining -= h
            h_prev = h
            h_allowed = min(h * s.growth, s.dt_max)
        ends.append(len(hs) - 1)
    return Schedule(np.array(hs), np.array(ws), np.array(cs), np.array(ends, dtype=int))
