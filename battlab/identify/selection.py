"""Stand-in experiment selection until the design module (``battlab.design``) exists.

For each parameter group, greedy D-optimal selection of ``m`` profiles from a candidate list: the weighted
Fisher information of the group's parameters (eqs. 22, 25: F = Σ_i S_iᵀ S_i / Q_i with the sensitivities at
the start cell) is built up one profile at a time, each time adding the profile that increases log det F most
(a small ridge keeps the first steps defined). Candidates that stop early at a voltage limit under the start
cell are skipped. The design module's convex D-optimal plan replaces this through ``battlab fit --plan``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import variance_of
from battlab.identify.forward import ForwardModel
from battlab.noise import NoiseModel
from protocols.profile import Profile


def information(
    forward: ForwardModel,
    cell: Cell,
    profiles: Sequence[Profile],
    names: Sequence[str],
    noise: NoiseModel | None = None,
) -> dict[object, np.ndarray]:
    """Per profile id: F_i = S_iᵀ S_i / Q_i (p × p, θ̄ units) at ``cell``; profiles that stop early are left out."""
    th = forward.theta_of(cell)
    out = {}
    for p in profiles:
        o = forward.run(th, p, p.soc0, sensitivities=list(names))
        if o.ended_by is None:
            out[p.id] = o.sensitivities.T @ o.sensitivities / variance_of(p, noise)
    return out


def greedy_d_optimal(info: dict[object, np.ndarray], m: int, ridge: float = 1e-9) -> list[object]:
    """Ids of ``m`` profiles chosen greedily to maximise log det Σ F_i."""
    chosen: list[object] = []
    if not info:
        return chosen
    p = next(iter(info.values())).shape[0]
    total = ridge * np.eye(p) * max(float(np.trace(sum(info.values()))) / p, 1.0)
    for _ in range(min(m, len(info))):
        best, best_val = None, -np.inf
        for pid, f in info.items():
            if pid in chosen:
                continue
            val = np.linalg.slogdet(total + f)[1]
            if val > best_val:
                best, best_val = pid, val
        chosen.append(best)
        total = total + info[best]
    return chosen
