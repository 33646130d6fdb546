"""``battlab diagnose`` as a function on values: :func:`diagnose` takes one :class:`DiagnoseOptions` and returns a
:class:`~battlab.diagnose.report.DiagnosisReport`: where the cell's simulation disagrees with logged data, which cause
of the catalog (:mod:`battlab.causes`) explains it, and whether its extension predicts data it was not fitted to.

1. The data are loaded, checked against the cell and split into training and held-out parts
   (:mod:`battlab.diagnose.data`), with the noise variance measured on each log's own voltage.
2. The cell is simulated on every experiment; the residual (measured − simulated) is analysed
   (:mod:`battlab.diagnose.residuals`) and drawn (:mod:`battlab.diagnose.figures`).
3. Each catalog cause is scored at its "off" value on the training part (:mod:`battlab.diagnose.directions`,
   :func:`battlab.diagnose.score.score_test`) with all 18 base parameters' directions projected out and the
   batch-means (block) variance, robust to correlated model error. A cause passes when its p-value (Hotelling's
   T² against F) is below ``alpha`` / (number of causes tested): Bonferroni. Each cause is tested on the
   directions of those of its parameters the data would detect somewhere in their search range; a cause not seen
   whose typical size lies below what the data detect is listed as ``undetectable`` with the experiment that would
   show it (:mod:`battlab.diagnose.testability`).
4. Confirmation (:mod:`battlab.diagnose.confirm`): the leading passing causes' extensions are fitted on the
   training part beside the base parameters that explain most of the residual, the base model gets the same fit;
   a cause is named only when its fitted extension's held-out RMSE is at least
   :data:`~battlab.diagnose.confirm.MIN_GAIN` below the base fit's; what the data cannot decide is said.
5. The summary and the verdict in words (:mod:`battlab.diagnose.summary`).

Progress goes to subscribers (:mod:`battlab.progress`) as ``note`` events of the task ``diagnose``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab import causes, parameters
from battlab.cell import Cell
from battlab.diagnose import testability
from battlab.diagnose.confirm import (
    CONFIRM,
    MAX_CONFIRM,
    MIMICKED,
    MIN_GAIN,
    N_BASE,
    S2_REFIT,
    SOME_GAIN,
    Z_MIN,
    candidates,
    confirm,
    mimicked_by,
    refit_names,
    relevance,
)
from battlab.diagnose.confirmation import Confirmation
from battlab.diagnose.data import (
    CAPACITY_FACTOR,
    HELD_OUT_FRACTION,
    MIN_COVERAGE,
    V_MARGIN,
    Part,
    Prepared,
    prepare,
    simulate_on,
    split,
)
from battlab.diagnose.report import DiagnosisReport
from battlab.diagnose.summary import summarise
from battlab.identify.data_files import Ambient
from battlab.progress import Reporter, Subscriber
from protocols.errors import InputError

__all__ = [
    "ALPHA",
    "BLOCK_MIN_S",
    "CAPACITY_FACTOR",
    "CONFIRM",
    "HELD_OUT_FRACTION",
    "MAX_CONFIRM",
    "MIMICKED",
    "MIN_COVERAGE",
    "MIN_GAIN",
    "N_BASE",
    "N_BLOCKS",
    "S2_REFIT",
    "SOME_GAIN",
    "V_MARGIN",
    "Z_MIN",
    "Confirmation",
    "DiagnoseOptions",
    "Part",
    "diagnose",
    "refit_names",
    "split",
]

#: family-wise false-alarm rate of the ranking (Bonferroni over the causes tested)
ALPHA = 0.01
#: the training residual's mean square over the noise, in a logged channel, above this (and mostly along the base
#: directions): the causes whose own directions take it up are fitted
S2_BASE = 2.0
#: contiguous blocks of the batch-means variance: about this many over the training part, each at least BLOCK_MIN_S
N_BLOCKS = 30
BLOCK_MIN_S = 60.0


@dataclass(frozen=True)
class DiagnoseOptions:
    """One diagnosis: ``data`` (paths), ``cell`` (a built-in name, a BPX file or a :class:`Cell`); ``held_out``:
    paths or file names among the data, or other files, to hold out (one or several); ``ambient`` [K] for data that
    do not log it; ``causes``: catalog keys to test (default :data:`battlab.diagnose.directions.DEFAULT_CAUSES`);
    ``also_fit``: causes whose extension is fitted on the same terms as a confirmation whatever the score tests say,
    reported in the summary's ``also_fitted`` (not used in the decision: an outside check of what the data can show);
    ``preparations``: (data file, the log of its preparation) pairs, each file started at its preparation's full charge
    with the preparation as unscored lead-in (:func:`battlab.diagnose.data.prepare`), at ``full_charge_soc`` (1 by
    definition; the SOC a fit of the same preparations found the full charge to leave); ``held_out_tail``: hold out
    only the final part of each held-out file, its beginning trains (:func:`battlab.diagnose.data.split`)."""

    data: tuple[str | Path, ...]
    cell: Cell | str | Path
    held_out: str | Path | Sequence[str | Path] | None = None
    soc0: float | None = None
    ambient: Ambient = None
    dt: float = 1.0
    fix_sign: bool = False
    causes: tuple[str, ...] | None = None
    alpha: float = ALPHA
    max_iter: int = 20
    also_fit: tuple[str, ...] = ()
    preparations: tuple[tuple[str | Path, str | Path], ...] = ()
    full_charge_soc: float = 1.0
    held_out_tail: bool = False

    def __post_init__(self) -> None:
        from battlab.diagnose.directions import DEFAULT_CAUSES

        object.__setattr__(self, "data", tuple(self.data))
        held = self.held_out
        object.__setattr__(self, "held_out", (held,) if isinstance(held, str | Path) else tuple(held or ()))
        object.__setattr__(self, "also_fit", tuple(self.also_fit))
        object.__setattr__(self, "preparations", tuple((str(a), str(b)) for a, b in self.preparations))
        given = {Path(p).resolve() for p in (*self.data, *self.held_out)}
        for d, _ in self.preparations:
            if Path(d).resolve() not in given:
                raise InputError(f"--preparation {d}=…: {d} is not one of the data files")
        if self.causes is not None:
            object.__setattr__(self, "causes", tuple(self.causes) or None)
        for c in (*(self.causes or ()), *self.also_fit):
            parameters.extension_parameters(c)
        for c in self.causes or ():
            if c not in DEFAULT_CAUSES:
                raise InputError(
                    f"cause {c!r} cannot be score-tested (its voltage is not differentiable at its off value); "
                    f"expected one of {', '.join(DEFAULT_CAUSES)}"
                )
        if self.soc0 is not None and not 0.0 <= self.soc0 <= 1.0:
            raise InputError(f"--soc0 {self.soc0:g}: a state of charge is between 0 and 1")
        if self.dt <= 0:
            raise InputError(f"--dt {self.dt:g} s: the resampling step must be positive")
        if not 0.5 <= self.full_charge_soc <= 1.0:
            raise InputError(f"full-charge SOC {self.full_charge_soc:g}: expected between 0.5 and 1")


@dataclass
class Residuals:
    """The cell on every experiment: times (concatenated), residual [V], current [A], SOC, noise variance [V²]."""

    t: np.ndarray
    r: np.ndarray
    current: np.ndarray
    soc: np.ndarray
    noise: np.ndarray
    analysis: Any


@dataclass
class Scores:
    """The score tests on the training part: the stacked channels (:class:`battlab.diagnose.mechanisms.Channels`,
    residual at the cell as given), the residual with all 18 base directions projected out, the share the base
    directions take, block length, detectable sizes, the ranking and what passes, the pairs the data cannot tell
    apart, the base parameters that mimic each cause, the threshold."""

    ch: Any
    r_projected: np.ndarray
    base_share: float
    block_s: float
    sizes: dict[str, dict[str, float]]
    ranked: list[Any]
    passing: list[Any]
    twins: list[tuple[str, str, float]]
    mimics: dict[str, list[str]]
    p_threshold: float
    base_passes: bool = False  # one cause's own directions explain most of a residual beyond its noise
    share: dict[str, float] = field(default_factory=dict)  # per cause: share of the residual along its own directions


def residual_step(prep: Prepared, fm: Any) -> Residuals:
    """Simulate the cell on all data and analyse the residual; a simulation that stops before half a data set is
    a mismatch of data and cell (one :class:`InputError`)."""
    from battlab.diagnose import residuals

    ts, rs, cur, socs, nvar = [], [], [], [], []
    offset = 0.0
    for p in prep.parts:
        e = p.experiment
        out = simulate_on(fm, e)
        n = out.voltage.size
        if n < MIN_COVERAGE * e.voltage.size:
            raise InputError(
                f"{e.name}: cell {prep.cell.name!r} stops at {100 * n / e.voltage.size:.0f} % of the data "
                f"({out.ended_by}): data and cell do not match"
            )
        if n < e.voltage.size:
            prep.warnings.append(
                f"{e.name}: the simulation stopped at {100 * n / e.voltage.size:.1f} % ({out.ended_by})"
            )
        a = min(e.lead_in, n - 1)  # the unscored lead-in is simulated, not analysed
        t = e.profile.t[:n]
        i = e.profile.current[:n]
        q = np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t))]) / 3600.0
        ts.append(t[a:] - t[a] + offset)
        offset = float(ts[-1][-1]) + 1.0
        rs.append((e.voltage[:n] - out.voltage)[a:])
        cur.append(i[a:])
        socs.append((e.soc0 + q / float(prep.base.capacity()))[a:])
        nvar.append(np.broadcast_to(np.asarray(e.variance, float), (e.voltage.size,))[a:n])
    tt, rr, ii, ss, vv = (np.concatenate(x) for x in (ts, rs, cur, socs, nvar))
    analysis = residuals.analyse(tt, rr + 0.0, np.zeros_like(rr), ii, soc=ss, noise_variance=vv)
    return Residuals(tt, rr, ii, ss, vv, analysis)


def _training_channels(prep: Prepared, fm: Any, keys: Sequence[str], say: Reporter) -> Any:
    """The training rows of every channel stacked (:class:`battlab.diagnose.mechanisms.Channels`): per training
    experiment its voltage rows, then its surface temperature's where logged, cut to the shortest simulation."""
    from battlab.diagnose.directions import extension_directions
    from battlab.diagnose.mechanisms import Channels

    lim = (float(prep.base["V_min"]) - V_MARGIN, float(prep.base["V_max"]) + V_MARGIN)
    rows: dict[str, list[np.ndarray]] = {"r": [], "J": [], "w": [], "t": [], "T": []}
    S_rows: dict[str, list[np.ndarray]] = {}
    offset = 0.0
    for e in prep.train:
        say("note", text=f"directions on {e.name}")
        b = simulate_on(fm, e, parameters.NAMES)
        dirs = {
            d.cause: d
            for d in extension_directions(
                prep.base, e.profile, e.soc0, (), causes=keys, ambient=e.ambient, T0=e.T0, v_limits=lim
            )
        }
        n = min([b.voltage.size, *(d.S.shape[0] for d in dirs.values())])
        a = min(e.lead_in, n - 1)  # rows [a, n): the unscored lead-in carries the state, it is not a channel row
        t = e.profile.t[a:n] - e.profile.t[a] + offset
        offset = float(t[-1]) + 1.0
        use_T = e.has_temperature and b.T_surface is not None and b.dT is not None
        w_V = np.broadcast_to(1.0 / np.asarray(e.variance, float), (e.voltage.size,))
        blocks = [(e.voltage[a:n] - b.voltage[a:n], b.sensitivities[a:n], w_V[a:n], False)]
        if use_T:
            assert e.temperature is not None
            ok = np.isfinite(e.temperature[a:n])
            blocks.append(
                (
                    np.where(ok, e.temperature[a:n] - b.T_surface[a:n], 0.0),
                    b.dT[a:n],
                    np.where(ok, 1.0 / e.t_variance, 0.0),
                    True,
                )
            )
        for r, J, w, is_T in blocks:
            rows["r"].append(r)
            rows["J"].append(J)
            rows["w"].append(np.broadcast_to(w, r.shape))
            rows["t"].append(t)
            rows["T"].append(np.full(r.size, is_T))
            for k, d in dirs.items():
                S = d.S_T if is_T else d.S
                S_rows.setdefault(k, []).append(np.zeros((n - a, d.S.shape[1])) if S is None else S[a:n])
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    S = {k: np.concatenate(v) for k, v in S_rows.items() if len(v) == len(rows["r"])}
    return Channels(cat["r"], cat["J"], S, cat["w"], cat["t"], cat["T"].astype(bool))


def score_step(prep: Prepared, fm: Any, o: DiagnoseOptions, say: Reporter) -> Scores:
    """Screen the causes on the training part (see the module docstring, item 3): each extension's score test
    beyond every base direction; each cause's share of the residual along its own directions (base parameters and
    extension); which causes mimic each other on these data."""
    from battlab.diagnose import score
    from battlab.diagnose.directions import DEFAULT_CAUSES
    from battlab.diagnose.mechanisms import mimics as mimic_pairs
    from battlab.diagnose.mechanisms import shares

    keys = tuple(o.causes or DEFAULT_CAUSES)
    ch = _training_channels(prep, fm, keys, say)
    r, J, w, t = ch.r, ch.J, ch.w, ch.t
    # the base model at its linearised best fit: what the 18 base parameters can absorb is taken out of the
    # residual (an extension's score test asks what it explains beyond them)
    rp = score.project_out(J, r[:, None], w)[:, 0]
    cost_raw = float(np.sum(w * r**2))
    base_share = 1.0 - float(np.sum(w * rp**2)) / cost_raw if cost_raw > 0 else 0.0
    block_s = max(BLOCK_MIN_S, float(t.max() - t.min()) / N_BLOCKS)
    tested = [k for k in keys if k in ch.S]
    p_threshold = o.alpha / max(len(tested) + 1, 1)  # the extensions and the base directions together
    sizes = {k: testability.detectable_sizes(k, rp, J, ch.S[k], w, t, p_threshold, block_s) for k in tested}
    for k in tested:  # each extension on the columns the data would detect somewhere in their range
        ch.S[k] = ch.S[k][:, testability.informed_columns(k, sizes[k])]
    mimics = {k: mimicked_by(J, ch.S[k], w, parameters.NAMES) for k in tested}
    results = [score.score_test(k, rp, J, ch.S[k], w, t, block_s=block_s) for k in tested]
    ranked = score.rank_causes(results)
    passing = [s for s in ranked if s.dof > 0 and s.p_value < p_threshold]
    # the residual beyond the noise lies mostly along one cause's own directions (its base parameters or its
    # extension, e.g. a loss of active material): the causes whose own directions take most of it are fitted (a
    # joint score test of 18 directions over ~30 blocks has too little power to screen, and a block-variance test
    # of an extension little more on a slow residual)
    # per channel: a voltage residual beyond its noise is not diluted by a temperature that the model follows
    s2 = max((float(np.mean((w * r**2)[rows])) for rows in (~ch.is_T, ch.is_T) if np.any(rows)), default=0.0)
    everyone = [c.key for c in causes.CAUSES if c.key in ch.S or (not c.parameters and c.base)]
    share = shares(ch, everyone)
    base_passes = s2 > S2_BASE and max(share.values(), default=0.0) > 0.5
    twins = score.indistinguishable(ranked, w) + [tw for tw in mimic_pairs(ch, everyone) if tw[1] in tested]
    return Scores(
        ch,
        rp,
        base_share,
        block_s,
        sizes,
        ranked,
        passing,
        twins,
        mimics,
        p_threshold,
        base_passes,
        share,
    )


@dataclass
class Decision:
    """What the held-out confirmation decided (:class:`battlab.diagnose.confirm.Verdict`), with the cell's own
    held-out errors, the base refit's and the causes' fits."""

    verdict: Any
    cell: Any
    base_fit: Any
    fits: list[Any]
    relevant: tuple[str, ...]
    #: base parameter → :func:`battlab.diagnose.confirm.relevance` to the training residual (what a cause's fit moves)
    relevance: dict[str, float] = field(default_factory=dict)

    @property
    def cause(self) -> str | None:
        return self.verdict.cause

    @property
    def confirmations(self) -> list[Confirmation]:
        return [f.confirmation for f in self.fits]


def _informed(key: str, sc: Scores, prep: Prepared) -> tuple[str, ...]:
    """The extension parameters of ``key`` its score test ran on (``KEY.NAME``), less those its cause declares the
    training data cannot inform (a temperature coefficient at one ambient: a fit of it extrapolates to nonsense)."""
    c = causes.cause(key)
    if not c.parameters or key not in sc.sizes:
        return ()
    names = [c.parameters[j].qualified for j in testability.informed_columns(key, sc.sizes[key])]
    bad = c.not_informed(names, prep.train, 0.01 * float(prep.base["Q_nom"]))
    return tuple(n for n in names if n not in bad)


def decide_step(prep: Prepared, fm: Any, sc: Scores, o: DiagnoseOptions, say: Reporter) -> Decision:
    """Fit the base refit and the leading passing causes on the training part; decide on the held-out part
    (:func:`battlab.diagnose.confirm.decide`)."""
    from battlab.diagnose.confirm import decide, mechanism_names, withhold
    from battlab.diagnose.held_out import held_out

    cell_held = held_out(fm, prep.base, prep.parts)
    relevant = refit_names(prep.base, sc.ch.J, sc.ch.r, sc.ch.w, parameters.NAMES)
    rel = dict(zip(parameters.NAMES, relevance(sc.ch.J, sc.ch.r, sc.ch.w), strict=True))
    # the base directions explain a residual beyond the noise: the causes that own the base refit's parameters may
    # be what it stands for (PyBaMM's faster kinetics, refitted by k_p, c_e0 and R_s_n)
    owners = [c.key for n in relevant if (c := causes.owner(n)) is not None] if sc.base_passes else []
    keys = candidates(sc.passing, sc.twins, sc.share if sc.base_passes else {}, owners, sc.base_share)
    if not keys:
        from battlab.diagnose.confirm import Verdict

        return Decision(Verdict(None, None, "cell", cell_held, None), cell_held, None, [], relevant, rel)
    specs = [("base", relevant)] + [
        (k, names) for k in keys if (names := mechanism_names(prep.base, k, _informed(k, sc, prep), rel))
    ]
    say(
        "note",
        text=f"fitting the base refit ({', '.join(relevant)}) and {', '.join(k for k, _ in specs[1:])} on the "
        "training part",
    )
    base_fit, *fits = confirm(prep.base, specs, prep.train, prep.parts, o.max_iter)
    i_rest = 0.01 * float(prep.base["Q_nom"])
    verdict = decide(cell_held, base_fit, fits, sc.block_s)
    # a cause these data cannot fit that scores above the named one on the training part (smaller p) may be what the
    # named cause's fit stands in for
    p = {s.cause: s.p_value for s in sc.passing}
    cannot_fit = {e["cause"] for e in testability.untestable(prep.train, None, i_rest)}
    untested = {k for k in cannot_fit & p.keys() if p[k] < p.get(verdict.cause or "", 1.0)}
    verdict = withhold(verdict, sc.twins, untested)
    return Decision(verdict, cell_held, base_fit, fits, relevant, rel)


def also_fit_step(prep: Prepared, d: Decision, sc: Scores, o: DiagnoseOptions, say: Reporter) -> list[dict[str, Any]]:
    """The ``also_fit`` causes fitted on the same terms as a confirmation (reported, not decided on)."""
    from battlab.diagnose.confirm import mechanism_names

    done = {f.key: f for f in d.fits}
    if d.base_fit is not None:
        done["base"] = d.base_fit
    todo = [k for k in dict.fromkeys(("base", *o.also_fit)) if k not in done]
    if todo:
        say("note", text=f"fitting {', '.join(todo)} on the training part (also_fit)")
        i_rest = 0.01 * float(prep.base["Q_nom"])

        def informed(k: str) -> tuple[str, ...]:
            c = causes.cause(k)
            bad = c.not_informed(c.qualified_names, prep.train, i_rest)
            return tuple(n for n in c.qualified_names if n not in bad)

        specs = [
            (k, d.relevant if k == "base" else mechanism_names(prep.base, k, informed(k), d.relevance or None))
            for k in todo
        ]
        done.update({c.key: c for c in confirm(prep.base, specs, prep.train, prep.parts, o.max_iter)})
    ref = d.verdict.base if d.verdict.base is not None else done["base"].held
    return [
        {
            **done[k].confirmation.__dict__,
            "rmse_base_mV": ref.rmse_mV,
            "gain": 1.0 - done[k].held.metric / ref.metric,
        }
        for k in o.also_fit
    ]


def diagnose(options: DiagnoseOptions, subscribers: Sequence[Subscriber] = ()) -> DiagnosisReport:
    """Diagnose the cell on logged data (see :class:`DiagnoseOptions` and the module docstring)."""
    from battlab.identify.forward import ForwardModel

    o = options
    t_start = time.perf_counter()
    say = Reporter("diagnose", subscribers)
    cell = o.cell if isinstance(o.cell, Cell) else Cell.load(o.cell)
    prep = prepare(
        o.data,
        cell,
        held_out=o.held_out,
        soc0=o.soc0,
        ambient=o.ambient,
        dt=o.dt,
        fix_sign=o.fix_sign,
        preparations=o.preparations,
        full_charge_soc=o.full_charge_soc,
        held_out_tail=o.held_out_tail,
    )
    steps: dict[str, float] = {"prepare": time.perf_counter() - t_start}

    def timed(name: str, f: Any, *args: Any) -> Any:
        t0 = time.perf_counter()
        out = f(*args)
        steps[name] = time.perf_counter() - t0
        return out

    say("note", text="simulating the cell on the data")
    fm = ForwardModel(prep.base, v_margin=V_MARGIN)
    res = timed("residual", residual_step, prep, fm)
    sc = timed("score tests", score_step, prep, fm, o, say)
    d = timed("confirmation fits", decide_step, prep, fm, sc, o, say)
    summary = summarise(prep, res, sc, d, o)
    if o.also_fit:
        summary["also_fitted"] = timed("also_fit", also_fit_step, prep, d, sc, o, say)
    summary["seconds"] = time.perf_counter() - t_start
    summary["seconds_by_step"] = steps
    base_fit = d.base_fit.confirmation if d.base_fit is not None else None
    return DiagnosisReport(summary, res.analysis, sc.ranked, d.confirmations, base_fit, cell.name, prep.warnings)
