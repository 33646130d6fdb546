"""``battlab diagnose`` as a function on values: where the cell's simulation disagrees with logged data, which
model extension explains it, and whether that extension predicts data it was not fitted to.

1. The data are loaded and turned into experiments as ``battlab fit`` and ``validate`` do (start SOC, ambient:
   :func:`battlab.identify.experiments.experiments_from_data`), with the noise variance measured on each log's
   own voltage (:func:`battlab.diagnose.residuals.measured_noise_variance`); data and cell that do not match (voltage
   outside the cell's window, rest voltage outside its OCV range, more charge than :data:`CAPACITY_FACTOR` times
   its capacity, a simulation that stops before half the data) are one :class:`InputError`.
2. Training and held-out parts: with one file its final :data:`HELD_OUT_FRACTION` of samples is held out; with
   several the last file is (or the one given as ``held_out``; a held-out file not among the data is added).
3. The cell is simulated on every experiment; the residual (measured − simulated) is analysed
   (:mod:`battlab.diagnose.residuals`) and drawn (:mod:`battlab.diagnose.figures`).
4. Each catalog cause is scored at its "off" value on the training part (:mod:`battlab.diagnose.directions`,
   :func:`battlab.diagnose.score.score_test`) with all 18 base parameters' directions projected out and the
   batch-means (block) variance, robust to correlated model error. A cause passes when its p-value (Hotelling's
   T² against F, see :mod:`battlab.diagnose.score`) is below ``alpha`` / (number of causes tested): Bonferroni, so
   the false-alarm rate of the whole ranking is at most ``alpha`` when the blocks outlast the error's correlation.
   Each cause is tested on the directions of those of its parameters the data would detect somewhere in their
   search range; the smallest detectable change of each parameter (:mod:`battlab.diagnose.testability`) is in
   the summary's ``detectable_size``, and a cause not seen whose typical size
   (:data:`battlab.diagnose.directions.TYPICAL`) lies below it is listed as ``undetectable`` ("too small to see on
   these data") with the experiment that would show it.
5. Confirmation: the leading :data:`CONFIRM` passing causes' extension parameters (and those of passing causes
   indistinguishable from them, :func:`battlab.diagnose.score.indistinguishable`) are fitted on the training
   part together with the :data:`N_BASE` base parameters whose directions explain most of the residual (among
   those the cell holds inside their search range: :func:`refit_names`); the base model gets the same fit of the
   same base parameters (same data, start, optimiser and stopping rule). A cause is
   named only when its fitted extension's RMSE on the held-out part is at least :data:`MIN_GAIN` below the base
   fit's (a flexible extension fitted to another cause's residual wins by less: a 1 % current-sensor gain error
   was taken up 27 % by the OCV shifts); a passing cause that wins by :data:`SOME_GAIN` to :data:`MIN_GAIN` is
   one the data cannot decide on (``cannot_tell``); otherwise the cause is null ("no significant discrepancy").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from battlab import parameters
from battlab.cell import Cell
from battlab.diagnose import testability
from battlab.diagnose.report import Confirmation, DiagnosisReport
from battlab.identify.data_files import Ambient, ambient_of, check_ambient_keys, load_all
from battlab.identify.experiments import Experiment
from battlab.threads import thread_map
from protocols.errors import InputError
from protocols.profile import Profile

#: share of one data file's samples held out (its end)
HELD_OUT_FRACTION = 0.3
#: family-wise false-alarm rate of the ranking (Bonferroni over the causes tested)
ALPHA = 0.01
#: contiguous blocks of the batch-means variance: about this many over the training part, each at least BLOCK_MIN_S
N_BLOCKS = 30
BLOCK_MIN_S = 60.0
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
#: more charge passed in one direction than this times the cell's capacity: data and cell do not match
CAPACITY_FACTOR = 1.5
#: a simulation that reaches less than this share of a data set: data and cell do not match
MIN_COVERAGE = 0.5
#: the mean squared residual over the data's own noise variance (:func:`residuals.measured_noise_variance`) above
#: this with no cause named: say whether a refit of the base parameters would explain it
S2_REFIT = 10.0
#: a cause whose direction keeps less than this share after the base directions are projected out is one the base
#: parameters mimic on these data
MIMICKED = 0.05
#: widen the cell's voltage window by this [V] when replaying logged data (as ``battlab validate`` does)
V_MARGIN = 0.15


@dataclass(frozen=True)
class Part:
    """One experiment and how it is split: samples [0, ``train``) are training, [``train``, n) held out."""

    experiment: Experiment
    train: int

    @property
    def n(self) -> int:
        return self.experiment.voltage.size

    def training(self) -> Experiment | None:
        """The training samples as an experiment of their own (None: fewer than 10)."""
        e = self.experiment
        if self.train < 10:
            return None
        if self.train >= self.n:
            return e
        k = self.train
        prof = Profile(e.profile.t[:k], e.profile.current[:k], id=e.name, soc0=e.soc0)
        var = np.broadcast_to(np.asarray(e.variance, float), (self.n,))[:k]
        return Experiment(e.name, prof, e.voltage[:k], e.soc0, var, e.ambient, e.T0)


def split(data_parts: list[tuple[str, list[Experiment]]], held_out: str | None) -> tuple[list[Part], str]:
    """Training and held-out parts of the experiments of each file (see the module docstring), and the name of
    the held-out data."""
    if held_out is None and len(data_parts) == 1:
        name, exps = data_parts[0]
        total = sum(e.voltage.size for e in exps)
        cut = int(round((1.0 - HELD_OUT_FRACTION) * total))
        parts, seen = [], 0
        for e in exps:
            parts.append(Part(e, int(np.clip(cut - seen, 0, e.voltage.size))))
            seen += e.voltage.size
        return parts, f"{name} (final {100 * HELD_OUT_FRACTION:.0f} %)"
    hold = data_parts[-1][0] if held_out is None else held_out
    parts = [Part(e, 0 if name == hold else e.voltage.size) for name, exps in data_parts for e in exps]
    return parts, hold


def _file_key(path: str | Path, data: Any) -> set[str]:
    p = Path(path)
    return {str(p), p.name, p.stem, p.name.removesuffix(".csv").removesuffix(".bdf"), str(data.name)}


def _check_capacity(data: Any, cell: Cell) -> None:
    q = np.concatenate([[0.0], np.cumsum(data.current[:-1] * np.diff(data.t))]) / 3600.0
    swing = float(q.max() - q.min())
    cap = float(cell.capacity())
    if swing > CAPACITY_FACTOR * cap:
        raise InputError(
            f"{data.source or data.name}: {swing:.3f} Ah passed in one direction, more than {CAPACITY_FACTOR:g} × "
            f"cell {cell.name!r}'s capacity {cap:.3f} Ah: data and cell do not match"
        )


def _measured_noise(e: Experiment, cell: Cell) -> Experiment:
    """``e`` with the noise variance measured on its own voltage
    (:func:`battlab.diagnose.residuals.measured_noise_variance`, steps of 1 % of the cell's capacity in A apart),
    at least the quantisation's: the noise model's level (the paper's regression on intensity, eqs. 37–40) holds
    for the paper's 2.7 Ah cell, and on a 12.5 Ah cell's hour it is over 1 V, which made s² and every
    "above the noise" judgement meaningless. ``e`` unchanged when too few steady samples."""
    from dataclasses import replace

    from battlab.diagnose.residuals import measured_noise_variance
    from battlab.identify.experiments import QUANTUM

    var = measured_noise_variance(e.voltage, e.profile.current, 0.01 * float(cell["Q_nom"]))
    return replace(e, variance=max(var, QUANTUM**2 / 12.0)) if np.isfinite(var) else e


def _simulate(fm: Any, e: Experiment, names: Sequence[str] = ()) -> Any:
    return fm.run(fm.theta_of(fm.cell), e.profile, e.soc0, ambient=e.ambient, T0=e.T0, sensitivities=names)


def _held_out_rmse(fm: Any, cell: Cell, parts: Sequence[Part]) -> float:
    """RMSE [mV] of ``cell`` on the held-out samples (each experiment simulated from its start), NaN-free part."""
    from battlab.identify.validation import predict

    err = []
    for p in parts:
        if p.train < p.n:
            pred = predict(fm, cell, p.experiment)
            e = pred[p.train :] - p.experiment.voltage[p.train :]
            err.append(e[np.isfinite(e)])
    e = np.concatenate(err) if err else np.zeros(0)
    return float(1e3 * np.sqrt(np.mean(e**2))) if e.size else float("nan")


def _confirm(
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
            _held_out_rmse(fm, res.cell, parts),
            bool(res.convergence.converged),
        )

    return thread_map(one, range(len(causes)), None if compiled else 1)


def _named(base_fit: Confirmation, confirmations: Sequence[Confirmation]) -> str | None:
    """The cause whose fitted extension predicts the held-out data best, if it beats the base fit by
    :data:`MIN_GAIN` (else None)."""
    winners = [c for c in confirmations if c.rmse_held_out_mV <= (1.0 - MIN_GAIN) * base_fit.rmse_held_out_mV]
    return min(winners, key=lambda c: c.rmse_held_out_mV).cause if winners else None


def _candidates(passing: Sequence[Any], twins: Sequence[tuple[str, str, float]]) -> list[Any]:
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


def _mimicked_by(J: np.ndarray, S: np.ndarray, w: np.ndarray, names: Sequence[str], n: int = 2) -> list[str]:
    """The ``n`` base parameters whose directions are most nearly parallel to the extension's first (|cos|, W)."""
    sw = np.sqrt(w)
    a = S[:, 0] * sw
    Jw = J * sw[:, None]
    den = np.sqrt(np.sum(Jw**2, axis=0)) * np.sqrt(np.sum(a**2))
    cos = np.abs(Jw.T @ a) / np.where(den > 0, den, np.inf)
    return [names[k] for k in np.argsort(cos)[::-1][:n] if cos[k] > 0]


def _cannot_tell(
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


def diagnose(
    data: Sequence[str | Path],
    cell: Cell | str,
    *,
    held_out: str | Path | None = None,
    soc0: float | None = None,
    ambient: Ambient = None,
    dt: float = 1.0,
    fix_sign: bool = False,
    causes: Sequence[str] | None = None,
    alpha: float = ALPHA,
    max_iter: int = 20,
    on_step: Any = None,
    also_fit: Sequence[str] = (),
) -> DiagnosisReport:
    """Diagnose ``cell`` on logged ``data`` (see the module docstring). ``held_out``: a path (or file name) among
    ``data``, or another file, to hold out; ``ambient`` [K] for data that do not log it; ``causes``: the catalog
    keys to test (default :data:`battlab.diagnose.directions.DEFAULT_CAUSES`); ``on_step(text)``: progress;
    ``also_fit``: catalog causes whose extension is fitted on the same terms as a confirmation (same base
    parameters, training data, optimiser) whatever the score tests say, their held-out RMSE against the same base
    fit in the summary's ``also_fitted`` (not used in the decision: an outside check of what the data can show)."""
    from battlab.diagnose import residuals, score
    from battlab.diagnose.directions import DEFAULT_CAUSES, TYPICAL, extension_directions
    from battlab.identify.experiments import experiments_from_data
    from battlab.identify.forward import ForwardModel

    t_start = time.perf_counter()
    say = on_step if callable(on_step) else (lambda _text: None)
    cell = cell if isinstance(cell, Cell) else Cell.load(cell)
    base = cell
    for key in list(cell.extensions):
        base = base.without_extension(key)
    paths = [str(p) for p in data]
    if held_out is not None and not any(str(held_out) in _file_key(p, Path(p)) for p in paths):
        paths.append(str(held_out))
    check_ambient_keys(paths, ambient)
    for c in causes or ():
        parameters.extension_parameters(c)
        if c not in DEFAULT_CAUSES:
            raise InputError(
                f"cause {c!r} cannot be score-tested (its voltage is not differentiable at its off value); "
                f"expected one of {', '.join(DEFAULT_CAUSES)}"
            )
    loaded, warned = load_all(paths, fix_sign=fix_sign)
    hold_name: str | None = None
    data_parts: list[tuple[str, list[Experiment]]] = []
    for p, d in zip(paths, loaded, strict=True):
        _check_capacity(d, base)
        exps = experiments_from_data(d, base, dt=dt, soc0=soc0, ambient=ambient_of(d, ambient))
        exps = [_measured_noise(e, base) for e in exps]
        data_parts.append((d.name, exps))
        if held_out is not None and str(held_out) in _file_key(p, d):
            hold_name = d.name
    parts, held_name = split(data_parts, hold_name)
    train = [e for e in (p.training() for p in parts) if e is not None]
    if not train:
        raise InputError("diagnose: no training data left (give more than the held-out file)")
    if all(p.train >= p.n for p in parts):
        raise InputError("diagnose: no held-out data (a file given as --held-out must be one of the data)")

    # 1. simulate the cell on all data: residual analysis
    say("simulating the cell on the data")
    fm = ForwardModel(base, v_margin=V_MARGIN)
    ts, rs, cur, socs, nvar = [], [], [], [], []
    offset = 0.0
    for p in parts:
        e = p.experiment
        out = _simulate(fm, e)
        n = out.voltage.size
        if n < MIN_COVERAGE * e.voltage.size:
            raise InputError(
                f"{e.name}: cell {cell.name!r} stops at {100 * n / e.voltage.size:.0f} % of the data "
                f"({out.ended_by}): data and cell do not match"
            )
        if n < e.voltage.size:
            warned.append(f"{e.name}: the simulation stopped at {100 * n / e.voltage.size:.1f} % ({out.ended_by})")
        t = e.profile.t[:n]
        ts.append(t - t[0] + offset)
        offset = float(ts[-1][-1]) + 1.0
        rs.append(e.voltage[:n] - out.voltage)
        i = e.profile.current[:n]
        cur.append(i)
        q = np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t))]) / 3600.0
        socs.append(e.soc0 + q / float(base.capacity()))
        nvar.append(np.broadcast_to(np.asarray(e.variance, float), (e.voltage.size,))[:n])
    tt, rr = np.concatenate(ts), np.concatenate(rs)
    analysis = residuals.analyse(
        tt,
        rr + 0.0,
        np.zeros_like(rr),
        np.concatenate(cur),
        soc=np.concatenate(socs),
        noise_variance=np.concatenate(nvar),
    )

    # 2. score tests on the training part
    base_names = parameters.NAMES
    lim = (float(base["V_min"]) - V_MARGIN, float(base["V_max"]) + V_MARGIN)
    isothermal = False
    keys = tuple(causes or DEFAULT_CAUSES)
    r_all: list[np.ndarray] = []
    J_all: list[np.ndarray] = []
    t_all: list[np.ndarray] = []
    w_all: list[np.ndarray] = []
    S_all: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    offset = 0.0
    for e in train:
        say(f"extension directions on {e.name}")
        b = _simulate(fm, e, base_names)
        dirs = {
            d.cause: d
            for d in extension_directions(
                base,
                e.profile,
                e.soc0,
                (),
                causes=keys,
                ambient=e.ambient,
                isothermal=isothermal,
                T0=e.T0,
                v_limits=lim,
            )
        }
        n = min([b.voltage.size, *(d.S.shape[0] for d in dirs.values())])
        r_all.append(e.voltage[:n] - b.voltage[:n])
        J_all.append(b.sensitivities[:n])
        t = e.profile.t[:n]
        t_all.append(t - t[0] + offset)
        offset = float(t_all[-1][-1]) + 1.0
        w_all.append(1.0 / np.broadcast_to(np.asarray(e.variance, float), (e.voltage.size,))[:n])
        for k in keys:
            if k in dirs:
                S_all[k].append(dirs[k].S[:n])
    r, J, t, w = (np.concatenate(x) for x in (r_all, J_all, t_all, w_all))
    # the base model at its linearised best fit: what the 18 base parameters can absorb is taken out of the
    # residual (the score tests assume a fitted base, Jᵀ W r ≈ 0; the score itself is unchanged by this)
    r_raw, r = r, score.project_out(J, r[:, None], w)[:, 0]
    cost_raw = float(np.sum(w * r_raw**2))
    base_share = 1.0 - float(np.sum(w * r**2)) / cost_raw if cost_raw > 0 else 0.0
    span = float(t[-1] - t[0])
    block_s = max(BLOCK_MIN_S, span / N_BLOCKS)
    tested = [k for k in keys if len(S_all[k]) == len(train)]
    S_of = {k: np.concatenate(S_all[k]) for k in tested}
    mimics = {k: _mimicked_by(J, S_of[k], w, base_names) for k in tested}
    p_threshold = alpha / max(len(tested), 1)
    sizes = {k: testability.detectable_sizes(k, r, J, S_of[k], w, t, p_threshold, block_s) for k in tested}
    results = [
        score.score_test(k, r, J, S_of[k][:, testability.informed_columns(k, sizes[k])], w, t, block_s=block_s)
        for k in tested
    ]
    ranked = score.rank_causes(results)
    passing = [s for s in ranked if s.dof > 0 and s.p_value < p_threshold]
    twins = score.indistinguishable(ranked, w)

    # 3. confirmation on held-out data
    base_fit: Confirmation | None = None
    confirmations: list[Confirmation] = []
    cause: str | None = None
    start_rmse = _held_out_rmse(fm, base, parts)
    relevant = refit_names(base, J, r_raw, w, base_names)
    if passing:
        candidates = [s.cause for s in _candidates(passing, twins)]
        also_with = f" and with {', '.join(candidates)}" if candidates else ""
        say(f"fitting the base model's {', '.join(relevant)}{also_with} on the training part")
        base_fit, *confirmations = _confirm(base, [None, *candidates], relevant, train, parts, max_iter)
        cause = _named(base_fit, confirmations)
        best = min(confirmations, key=lambda c: c.rmse_held_out_mV)
        chosen = next(c for c in confirmations if c.cause == cause) if cause else best
        gain = {
            "rmse_before_mV": base_fit.rmse_held_out_mV,
            "rmse_after_mV": chosen.rmse_held_out_mV,
            "held_out": held_name,
            "cause_fitted": chosen.cause,
            "rmse_cell_mV": start_rmse,
        }
        verdict = (
            f"{cause} passes its score test and its fitted extension lowers the held-out RMSE "
            f"{base_fit.rmse_held_out_mV:.2f} → {chosen.rmse_held_out_mV:.2f} mV"
            if cause
            else f"score tests passed ({', '.join(s.cause for s in passing)}) but no fitted extension lowered the "
            f"held-out RMSE by {100 * MIN_GAIN:.0f} % against the same base fit"
        )
    else:
        gain = {"rmse_before_mV": start_rmse, "rmse_after_mV": None, "held_out": held_name, "rmse_cell_mV": start_rmse}
        verdict = "no cause passes its score test"
    white_var = float(np.mean(np.concatenate(nvar)))  # each log's noise, measured on its own voltage
    s2_white = float(np.mean(rr[np.isfinite(rr)] ** 2) / max(white_var, 1e-300))
    if cause is None and s2_white > S2_REFIT and base_share > 0.5:
        verdict += (
            f"; the residual is {s2_white:.3g} × the noise level, but {100 * base_share:.0f} % of it lies along "
            "the base parameters' directions: refit them (battlab fit)"
        )
    cannot_tell = _cannot_tell(
        cause,
        confirmations,
        base_fit.rmse_held_out_mV if base_fit else float("nan"),
        ranked,
        mimics,
        s2_white,
        base_share,
    )
    untestable = testability.untestable(train, cause, 0.01 * float(base["Q_nom"]))
    seen = {cause} | {s.cause for s in passing} | {c["cause"] for c in cannot_tell + untestable}
    undetectable = testability.undetectable(sizes, seen, TYPICAL)
    if undetectable:
        verdict += "; too small to see on these data: " + ", ".join(c["cause"] for c in undetectable)
    also: list[dict[str, Any]] = []
    if also_fit:
        done: dict[str | None, Confirmation] = {c.cause: c for c in confirmations}
        if base_fit is not None:
            done[None] = base_fit
        for k in also_fit:
            parameters.extension_parameters(k)
        todo = [k for k in dict.fromkeys((None, *also_fit)) if k not in done]
        if todo:
            say(f"fitting {', '.join(k or 'the base model' for k in todo)} on the training part (also_fit)")
            done.update(zip(todo, _confirm(base, todo, relevant, train, parts, max_iter), strict=True))
        ref = done[None]
        for k in also_fit:
            c = done[k]
            also.append(
                {
                    **c.__dict__,
                    "rmse_base_mV": ref.rmse_held_out_mV,
                    "gain": 1.0 - c.rmse_held_out_mV / ref.rmse_held_out_mV,
                }
            )
    if cannot_tell:
        verdict += "; cannot tell " + ", ".join(c["cause"] for c in cannot_tell) + " on these data"
    summary: dict[str, Any] = {
        "cause": cause,
        "cannot_tell": cannot_tell,
        "untestable": untestable,
        "undetectable": undetectable,
        "detectable_size": sizes,
        "ranking": [
            {**row, "passes": bool(s.dof > 0 and s.p_value < p_threshold), "mimicked_by": mimics[s.cause]}
            for row, s in zip(score.summary(ranked), ranked, strict=True)
        ],
        "extension_gain": gain,
        "verdict": verdict,
        "threshold": {
            "p_value": p_threshold,
            "rule": f"block-variance score test, Hotelling T² vs F, Bonferroni alpha {alpha:g} over {len(ranked)} "
            f"causes, blocks of {block_s:.0f} s",
        },
        "indistinguishable": [[a, b, c] for a, b, c in twins],
        "base_explained": base_share,
        "white_noise_mV": 1e3 * float(np.sqrt(white_var)),
        "residual_over_noise": s2_white,
        "residual": analysis.summary(),
        "data": [name for name, _ in data_parts],
        "held_out": held_name,
        "confirmations": [c.__dict__ for c in ([base_fit] if base_fit else []) + confirmations],
        "warnings": warned,
    }
    if also_fit:
        summary["also_fitted"] = also
    summary["seconds"] = time.perf_counter() - t_start
    return DiagnosisReport(summary, analysis, ranked, confirmations, base_fit, cell.name, warned)
