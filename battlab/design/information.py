"""Fisher information of library profiles (eqs. 22, 25) from a sensitivity store, with the noise model (eqs. 36–40).

For profile i with voltage sensitivities S_i (n_i × p, dV/dθ̄ at 1 s samples) and the scalar measurement variance
Q_i = q̂_i² [V²] (eq. 40, the covariance is Q_i times the identity), F_i = S_iᵀ S_i / Q_i. The store keeps R_i with
R_iᵀ R_i = S_iᵀ S_i, so the weighted sensitivities R_i / q_i stand in for S_i / q_i everywhere (same Gram matrix,
same orthogonalisation) at p rows instead of n_i.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab.design.sweep import CONVENTIONAL, GROUP, SensitivityStore
from battlab.noise import NoiseModel
from protocols.errors import InputError


@dataclass(frozen=True)
class Information:
    """Per-profile information of the usable profiles: ids, q [V], R (L, p, p) unweighted, costs.

    ``F`` is (L, p, p) with F_i = R_iᵀ R_i / q_i² [1/θ̄²]; ``W`` = R_i / q_i (weighted square-root information).
    """

    ids: tuple[Any, ...]
    names: tuple[str, ...]
    R: np.ndarray
    q: np.ndarray
    meta: tuple[dict[str, Any], ...] = field(default=())
    excluded: dict[Any, str] = field(default_factory=dict)

    @property
    def W(self) -> np.ndarray:
        return self.R / self.q[:, None, None]

    @property
    def F(self) -> np.ndarray:
        W = self.W
        return np.einsum("lki,lkj->lij", W, W)

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, params: Sequence[str]) -> np.ndarray:
        """F_i restricted to ``params`` (the others fixed): (L, k, k)."""
        idx = [self.index(n) for n in params]
        return self.F[:, idx][:, :, idx]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"parameter {name!r} is not in the store (it has {', '.join(self.names)})") from None

    def cost(self, what: str) -> np.ndarray:
        """Per-profile cost for a budget (eqs. 32–35): ``duration`` [s] or ``throughput`` [Ah]."""
        if what == "duration":
            return np.array([m["duration"] for m in self.meta], float)
        if what == "throughput":
            return np.array([m["throughput"] for m in self.meta], float)
        raise InputError(f"unknown cost {what!r}: expected 'duration' or 'throughput'")


def load(
    store: SensitivityStore,
    noise: NoiseModel | None = None,
    *,
    where: str = GROUP,
    include_flagged: bool = False,
) -> Information:
    """The information of every usable profile in ``store`` (status ok; flagged too if asked).

    Failed profiles, and flagged ones unless ``include_flagged``, are listed in ``excluded`` with their reason.
    """
    noise = noise or NoiseModel()
    ok = ("ok", "flagged") if include_flagged else ("ok",)
    ids, Rs, qs, meta = [], [], [], []
    excluded: dict[Any, str] = {}
    for pid in store.ids(where=where):
        info = store.info(pid, where)
        if info["status"] not in ok:
            excluded[pid] = f"{info['status']}: {info['reason']}"
            continue
        prof = store.simulated_profile(pid, where)
        ids.append(pid)
        Rs.append(store.R(pid, where))
        qs.append(noise.q(prof))
        meta.append(
            {
                "id": pid,
                "kind": info["kind"],
                "soc0": float(info["soc0"]),
                "params": info["params"],
                "duration": prof.duration,
                "throughput": prof.charge_throughput,
                "peak_current_A": prof.max_abs_current,
                "T_surface_max_C": float(info.get("T_surface_max_C", np.nan)),
            }
        )
    if not ids:
        raise InputError(f"{store.path}: no usable profiles in /{where} ({len(excluded)} excluded)")
    return Information(tuple(ids), store.names, np.array(Rs), np.array(qs), tuple(meta), excluded)


def conventional(store: SensitivityStore, noise: NoiseModel | None = None) -> Information | None:
    """The conventional test set's information, or None when the store has none."""
    if not store.ids(where=CONVENTIONAL):
        return None
    return load(store, noise, where=CONVENTIONAL, include_flagged=True)
