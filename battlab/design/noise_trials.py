"""Which library profiles measure the tester's noise: repeated trials of pulse profiles that only charge and that
only discharge, spread over the intensities (eq. 38 fits one curve per direction), gentle enough that a trial never
ends at a safety limit. The campaign's noise stage and ``battlab design --noise-trials`` both pick them here."""

from __future__ import annotations

from typing import Any

import numpy as np

from battlab.cell import Cell

#: how far [V] a noise profile simulated on the start cell must stay above V_min and below V_max (the truth may be
#: more polarised than the start: 0.3-0.5 V more at the end of long discharges, tens of mV on charge)
NOISE_MARGIN_V = (0.2, 0.1)
#: the largest current [C] of a noise profile
NOISE_MAX_C = 3.0


def noise_profiles(lib: Any, per_direction: int, cell: Cell | None = None, max_s: float = 3600.0) -> list[Any]:
    """Pulse profiles that only charge and that only discharge, ``per_direction`` of each, spread over the range of
    intensities (eq. 38 fits one line per direction), from the library's outer start SOCs (discharges from 0.8,
    charges from 0.2: their 1 Ah, 37 % of SOC, stays away from the ends, where the truth may be far more polarised
    than the start cell). With ``cell``: at most :data:`NOISE_MAX_C`, and a profile whose simulation on ``cell``
    comes within :data:`NOISE_MARGIN_V` of a voltage limit is passed over for the next gentler one (a repeated
    trial must not end at a safety limit). Profiles longer than ``max_s`` [s] are left out."""
    from battlab.noise import direction, intensity

    out = []
    cell_c = float(cell["Q_nom"]) if cell is not None else 0.0
    for d in ("discharge", "charge"):
        fits = (lambda p: p.soc0 >= 0.8) if d == "discharge" else (lambda p: p.soc0 <= 0.2)
        gentle = (
            (lambda p: float(np.abs(p.current).max()) <= NOISE_MAX_C * cell_c) if cell is not None else (lambda p: True)
        )
        cands = [
            p
            for p in lib
            if p.kind == "pulse" and direction(p).value == d and fits(p) and gentle(p) and p.duration <= max_s
        ]
        cands.sort(key=intensity)
        if not cands or per_direction < 1:
            continue
        targets = np.unique(np.linspace(0, len(cands) - 1, per_direction).round().astype(int))
        used: set[int] = set()
        for k in targets:
            order = [j for j in range(k, -1, -1) if j not in used]  # the target, else the next gentler one
            for j in order:
                if cell is None or _in_window(cell, cands[j]):
                    used.add(j)
                    out.append(cands[j])
                    break
    return out


def _in_window(cell: Cell, prof: Any) -> bool:
    from battlab.simulation import simulate

    res = simulate(cell, prof, soc0=float(prof.soc0))
    v = res.voltage
    lo, hi = float(cell["V_min"]) + NOISE_MARGIN_V[0], float(cell["V_max"]) - NOISE_MARGIN_V[1]
    return res.ended_by is None and v.min() >= lo and v.max() <= hi
