"""Causes as mechanisms in the score tests: each cause of the catalog (:mod:`battlab.causes`) is tested on all of its
own directions, its base parameters' (a residual its base parameters explain is that cause: "refit these") and
its extension's (a residual that needs the extension), with only the *other* causes' base directions projected out;
on every logged channel (voltage, and the surface temperature where it is logged), each row weighted by its own
noise level.

:class:`Channels` holds the training data stacked this way; :func:`own_and_others` splits the 18 base columns by
owner; :func:`score_mechanisms` runs :func:`battlab.diagnose.score.score_test` per cause; :func:`shares` says how much
of the residual each cause's own directions alone would take up (what a verdict reports when nothing is named).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from battlab import causes, parameters
from battlab.diagnose import score


@dataclass
class Channels:
    """Training rows of every channel, stacked: residual r (measured − simulated, at the cell as given), the 18
    base parameters' sensitivities J (θ̄), each tested cause's extension sensitivities S (its informed columns),
    weights w (1/variance of the row's channel), time t [s] (one axis for the blocks) and which rows are the
    temperature's."""

    r: np.ndarray
    J: np.ndarray
    S: dict[str, np.ndarray]
    w: np.ndarray
    t: np.ndarray
    is_T: np.ndarray

    @property
    def n_voltage(self) -> int:
        return int(np.sum(~self.is_T))

    @property
    def n_temperature(self) -> int:
        return int(np.sum(self.is_T))


def own_and_others(key: str, names: Sequence[str] = parameters.NAMES) -> tuple[list[int], list[int]]:
    """Columns of the base parameters ``names`` that cause ``key`` owns, and the others'."""
    base = set(causes.cause(key).base)
    own = [k for k, n in enumerate(names) if n in base]
    return own, [k for k in range(len(names)) if k not in own]


def directions(ch: Channels, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(the cause's own directions: its extension's columns then its base parameters', the other causes' base
    directions)."""
    own, others = own_and_others(key)
    parts = [ch.S[key]] if key in ch.S and ch.S[key].size else []
    parts.append(ch.J[:, own])
    return np.hstack(parts), ch.J[:, others]


def score_mechanisms(ch: Channels, keys: Sequence[str], block_s: float) -> list[score.ScoreResult]:
    """The score test of each cause as a mechanism (its own directions, the other causes' base directions projected
    out), with the batch-means variance over blocks of ``block_s`` seconds."""
    out = []
    for k in keys:
        S, J = directions(ch, k)
        if S.shape[1] == 0:
            continue
        # the test at the constrained fit: the other causes' base parameters fitted (linearised), this cause's at
        # its reference; its residual is what they leave (and what the block variance is taken of)
        r = score.project_out(J, ch.r[:, None], ch.w)[:, 0]
        out.append(score.score_test(k, r, J, S, ch.w, ch.t, block_s=block_s))
    return out


def mimics(ch: Channels, keys: Sequence[str], share: float = 0.95) -> list[tuple[str, str, float]]:
    """Pairs (a, b, s): the extension of cause b lies (a share s ≥ ``share`` of its W-norm) in the span of cause a's
    own directions on these data, so a fit of a can take up b's effect (a series resistance and the film
    resistances at one temperature). Each such b is fitted beside a when a passes."""
    sw = np.sqrt(ch.w)[:, None]
    out = []
    for a in keys:
        Sa, _ = directions(ch, a)
        if Sa.shape[1] == 0:
            continue
        Q, _, rank = score._qr_rank(Sa * sw)
        if not rank:
            continue
        for b in keys:
            if b == a or b not in ch.S or not ch.S[b].size:
                continue
            Sb = ch.S[b] * sw
            total = float(np.sum(Sb**2))
            inside = float(np.sum((Q.T @ Sb) ** 2)) / total if total > 0 else 0.0
            if inside >= share:
                out.append((a, b, inside))
    return out


def shares(ch: Channels, keys: Sequence[str]) -> dict[str, float]:
    """Per cause: the share of the weighted residual its own directions alone take up (a linearised refit of its
    parameters: ‖P_c r‖²_W / ‖r‖²_W)."""
    sw = np.sqrt(ch.w)
    rw = ch.r * sw
    total = float(rw @ rw)
    out: dict[str, float] = {}
    for k in keys:
        S, _ = directions(ch, k)
        if S.shape[1] == 0 or total <= 0:
            continue
        Q, _, rank = score._qr_rank(S * sw[:, None])
        out[k] = float(np.sum((Q.T @ rw) ** 2) / total) if rank else 0.0
    return out


def share_text(share: Mapping[str, float], n: int = 4) -> str:
    """``"electrolyte 41 %, kinetics 22 %"``: the largest shares first."""
    top = sorted(share.items(), key=lambda kv: -kv[1])[:n]
    return ", ".join(f"{k} {100 * v:.0f} %" for k, v in top)


__all__ = ["Channels", "directions", "mimics", "own_and_others", "score_mechanisms", "share_text", "shares"]
