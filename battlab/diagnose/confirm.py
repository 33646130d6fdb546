"""The held-out confirmation of a diagnosis: the leading causes' extensions fitted on the training part beside the
base parameters that explain most of the residual, the base model given the same fit, and the cause named only when
its fit predicts the held-out part clearly better; and what the data cannot decide.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.diagnose import testability
from battlab.diagnose.data import V_MARGIN, Part, held_out_rmse
from battlab.diagnose.report import Confirmation
from battlab.identify.experiments import Experiment
from battlab.threads import thread_map
from protocols.errors import InputError

#: passing causes whose extension is fitted and checked on held-out data
CONFIRM = 4
#: at most this many causes fitted (the leading ones and those indistinguishable from them)
MAX_CONFIRM = 5
#: base parameters fitted beside an extension (and alone, for the base model's fair comparison)
N_BASE = 3
#: relative held-out RMSE gain an extension must show to be named
MIN_GAIN = 0.3
#: relative held-out RMSE gain of a passing cause's fitted extension below which its passing is taken as chance
SOME_GAIN = 0.02
#: the mean squared residual over the data's own noise variance (:func:`residuals.measured_noise_variance`) above
#: this with no cause named: say whether a refit of the base parameters would explain it
S2_REFIT = 10.0
#: a cause whose direction keeps less than this share after the base directions are projected out is one the base
#: parameters mimic on these data
MIMICKED = 0.05


def confirm(
    cell: Cell,
    causes: Sequence[str | None],
    base_names: Sequence[str],
    train: Sequence[Experiment],
    parts: Sequence[Part],
    max_iter: int,
) -> list[Confirmation]:
    """Per cause (None: the base model alone): fit ``base_names`` and the cause's extension parameters on
    ``train``, and the held-out RMSE. The models are built one after the other, their fits then run side by side."""
    from battlab.identify.fit import Options, fit
    from battlab.identify.forward import ForwardModel

    models = [cell if c is None else cell.with_extension(c) for c in causes]
    fms = [ForwardModel(m, v_margin=V_MARGIN) for m in models]
    compiled = all(fm.thread_safe for fm in fms)

    def one(k: int) -> Confirmation:
        cause, model, fm = causes[k], models[k], fms[k]
        names = tuple(base_names) + (() if cause is None else tuple(p.qualified for p in parameters.EXTENSIONS[cause]))
        res = fit(model, list(train), names, options=Options(max_nfev=max_iter), forward=fm)
        rmse_train = float(np.sqrt(np.mean([v**2 for v in res.rmse_mV.values()]))) if res.rmse_mV else float("nan")
        return Confirmation(
            cause or "base",
            names,
            {n: float(res.cell.value(n)) for n in names},
            rmse_train,
            held_out_rmse(fm, res.cell, parts),
            bool(res.convergence.converged),
        )

    return thread_map(one, range(len(causes)), None if compiled else 1)


def named(base_fit: Confirmation, confirmations: Sequence[Confirmation]) -> str | None:
    """The cause whose fitted extension predicts the held-out data best, if it beats the base fit by
    :data:`MIN_GAIN` (else None)."""
    winners = [c for c in confirmations if c.rmse_held_out_mV <= (1.0 - MIN_GAIN) * base_fit.rmse_held_out_mV]
    return min(winners, key=lambda c: c.rmse_held_out_mV).cause if winners else None


def candidates(passing: Sequence[Any], twins: Sequence[tuple[str, str, float]]) -> list[Any]:
    """The causes to fit: the leading :data:`CONFIRM` passing ones, and any passing cause the data cannot tell
    apart from one of them (their scores rank such twins by chance), at most :data:`MAX_CONFIRM`."""
    lead = list(passing[:CONFIRM])
    names = {s.cause for s in lead}
    alike = {b if a in names else a for a, b, _ in twins if (a in names) != (b in names)}
    lead += [s for s in passing[CONFIRM:] if s.cause in alike]
    return lead[:MAX_CONFIRM]


#: a base parameter the cell holds up to this far outside its search range (normalised θ̄) is still refitted (from
#: the bound); farther out it is left at the cell's value
RANGE_SLACK = 0.2


def refit_names(cell: Cell, J: np.ndarray, r: np.ndarray, w: np.ndarray, names: Sequence[str]) -> tuple[str, ...]:
    """The :data:`N_BASE` base parameters whose directions explain most of the residual ``r`` (|cos|, W), among
    those ``cell`` holds inside their search range (or within :data:`RANGE_SLACK` of it, normalised: a BPX cell's
    film resistances of 0 start at their small lower bounds) and can take anywhere in it: one held far outside it
    (a BPX cell's transference number or kinetics beside the built-in ranges) would start its fit clipped to a
    bound, worse than the cell, and the extensions would then be compared against that damage instead of against
    the cell; one whose range holds impossible cells (a BPX cell's eps_e_n up to 0.45 beside its eps_s_n 0.69)
    would stop the fit that tries them."""
    Jw = J * np.sqrt(w)[:, None]
    norm = np.sqrt(np.sum(Jw**2, axis=0))
    relevance = np.abs(Jw.T @ (r * np.sqrt(w))) / np.where(norm > 0, norm, np.inf)

    def fittable(name: str) -> bool:
        if not -RANGE_SLACK <= cell.normalised(name) <= 1.0 + RANGE_SLACK:
            return False
        try:
            cell.with_normalised(**{name: 0.0}).with_normalised(**{name: 1.0})
        except InputError:
            return False
        return True

    inside = np.array([fittable(n) for n in names])
    order = [k for k in np.argsort(relevance)[::-1] if inside[k]]
    return tuple(names[k] for k in order[:N_BASE])


def mimicked_by(J: np.ndarray, S: np.ndarray, w: np.ndarray, names: Sequence[str], n: int = 2) -> list[str]:
    """The ``n`` base parameters whose directions are most nearly parallel to the extension's first (|cos|, W)."""
    sw = np.sqrt(w)
    a = S[:, 0] * sw
    Jw = J * sw[:, None]
    den = np.sqrt(np.sum(Jw**2, axis=0)) * np.sqrt(np.sum(a**2))
    cos = np.abs(Jw.T @ a) / np.where(den > 0, den, np.inf)
    return [names[k] for k in np.argsort(cos)[::-1][:n] if cos[k] > 0]


def cannot_tell(
    cause: str | None,
    confirmations: Sequence[Confirmation],
    base_rmse: float,
    ranked: Sequence[Any],
    mimics: dict[str, list[str]],
    s2: float | None,
    base_share: float,
) -> list[dict[str, Any]]:
    """The causes these data cannot decide on, each with why and the experiment (library profile kind) that would:
    with no cause named, those that pass their score test and whose fitted extension wins on held-out data by
    :data:`SOME_GAIN` to :data:`MIN_GAIN` (a smaller win: the pass was chance), and (when the residual is over
    :data:`S2_REFIT` × the noise level and the base directions hold most of it) those the base parameters mimic
    (under :data:`MIMICKED` of their direction left). Empty: the data decide (a cause named, or nothing beyond the
    noise)."""
    if cause is None:
        out = {
            c.cause: f"passes its score test, and its fitted extension lowers the held-out RMSE by "
            f"{100 * (1 - c.rmse_held_out_mV / base_rmse):.0f} %, less than the {100 * MIN_GAIN:.0f} % that names it"
            for c in confirmations
            if c.rmse_held_out_mV <= (1.0 - SOME_GAIN) * base_rmse
        }
        if s2 is not None and s2 > S2_REFIT and base_share > 0.5:
            for s in ranked:
                if s.projected_norm < MIMICKED and s.cause not in out:
                    out[s.cause] = (
                        f"its effect on these data lies along the base parameters' ({', '.join(mimics[s.cause])})"
                    )
    else:
        out = {}
    return [testability.cause_entry(c, w) for c, w in out.items()]
