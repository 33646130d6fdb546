"""A diagnosis's data: logged files as experiments (start SOC, ambient, the noise measured on each log's own
voltage), checked against the cell, split into training and held-out parts.

Training and held-out parts: with one file its final :data:`HELD_OUT_FRACTION` of samples is held out; with several
the last file is (or those given as ``held_out``; a held-out file not among the data is added); with ``tail`` only the
final :data:`HELD_OUT_FRACTION` of each held-out file is, its beginning trains (an experiment at a condition no other
file reaches, e.g. another ambient: the fits must see part of it to pin what only it shows, and predict the rest).
Data and cell that do not match (voltage outside the cell's window, rest voltage outside its OCV range, more charge than
:data:`CAPACITY_FACTOR` times its capacity, a simulation that stops before half the data) are one
:class:`InputError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.identify.data_files import Ambient, ambient_of, check_ambient_keys, load_all
from battlab.identify.experiments import Experiment
from protocols.errors import InputError
from protocols.profile import Profile

#: share of one data file's samples held out (its end)
HELD_OUT_FRACTION = 0.3
#: more charge passed in one direction than this times the cell's capacity: data and cell do not match
CAPACITY_FACTOR = 1.5
#: a simulation that reaches less than this share of a data set: data and cell do not match
MIN_COVERAGE = 0.5
#: widen the cell's voltage window by this [V] when replaying logged data (as ``battlab validate`` does)
V_MARGIN = 0.15
#: the surface temperature's model-form allowance [K], added in quadrature to its measured noise: a lumped or
#: two-node heat balance reproduces another implementation's surface temperature of the same cell to no better than
#: this (measured: battlab's two-node model against PyBaMM's lumped one, 0.04-0.09 K RMS over a 2.5-3 K rise on 4 h
#: profiles), and a surface thermocouple's resolution is about as much. Below it a temperature error is not
#: evidence of a cause (against a 0.05 K sensor noise alone, the null's 0.09 K named a thermal cause).
T_MODEL_K = 0.1


@dataclass(frozen=True)
class Part:
    """One experiment and how it is split: samples [0, ``train``) are training, [``train``, n) held out."""

    experiment: Experiment
    train: int

    @property
    def n(self) -> int:
        return self.experiment.voltage.size

    @property
    def held(self) -> slice:
        """The held-out samples (never the unscored lead-in)."""
        return slice(max(self.train, self.experiment.lead_in), self.n)

    def training(self) -> Experiment | None:
        """The training samples as an experiment of their own, with its lead-in (None: fewer than 10 scored)."""
        from dataclasses import replace

        e = self.experiment
        if self.train - e.lead_in < 10:
            return None
        if self.train >= self.n:
            return e
        k = self.train
        prof = Profile(e.profile.t[:k], e.profile.current[:k], id=e.name, soc0=e.soc0)
        var = np.broadcast_to(np.asarray(e.variance, float), (self.n,))[:k]
        cut = {f: getattr(e, f)[:k] for f in ("temperature", "truth", "mask") if getattr(e, f) is not None}
        return replace(e, profile=prof, voltage=e.voltage[:k], variance=var, **cut)


def _tail_parts(exps: list[Experiment]) -> list[Part]:
    """One file's experiments with the final :data:`HELD_OUT_FRACTION` of their samples held out."""
    total = sum(e.voltage.size for e in exps)
    cut = int(round((1.0 - HELD_OUT_FRACTION) * total))
    parts, seen = [], 0
    for e in exps:
        parts.append(Part(e, int(np.clip(cut - seen, 0, e.voltage.size))))  # a lead-in is never held out
        seen += e.voltage.size
    return parts


def split(
    data_parts: list[tuple[str, list[Experiment]]], held_out: Sequence[str] | str | None, tail: bool = False
) -> tuple[list[Part], str]:
    """Training and held-out parts of the experiments of each file (see the module docstring), and the name of
    the held-out data (several: joined by " + ")."""
    hold = (held_out,) if isinstance(held_out, str) else tuple(held_out or ())
    if not hold and len(data_parts) == 1:
        name, exps = data_parts[0]
        return _tail_parts(exps), f"{name} (final {100 * HELD_OUT_FRACTION:.0f} %)"
    hold = hold or (data_parts[-1][0],)
    parts = []
    for name, exps in data_parts:
        if name not in hold:
            parts += [Part(e, e.voltage.size) for e in exps]
        else:
            parts += _tail_parts(exps) if tail else [Part(e, 0) for e in exps]
    names = " + ".join(dict.fromkeys(hold))
    return parts, f"{names} (final {100 * HELD_OUT_FRACTION:.0f} %)" if tail else names


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
    """``e`` with its temperature's noise variance widened by the model-form allowance :data:`T_MODEL_K`, and the
    voltage's noise variance measured on its own voltage (:func:`battlab.diagnose.residuals.measured_noise_variance`,
    steps of 1 % of the cell's capacity in A apart), at least the quantisation's: the noise model's level (the
    paper's regression on intensity, eqs. 37–40) holds for the paper's 2.7 Ah cell, and on a 12.5 Ah cell's hour it
    is over 1 V, which made s² and every "above the noise" judgement meaningless (the voltage's is left as it is
    when too few steady samples)."""
    from dataclasses import replace

    from battlab.diagnose.residuals import measured_noise_variance
    from battlab.identify.experiments import QUANTUM

    var = measured_noise_variance(e.voltage, e.profile.current, 0.01 * float(cell["Q_nom"]))
    if e.has_temperature:
        e = replace(e, t_variance=e.t_variance + T_MODEL_K**2)
    return replace(e, variance=max(var, QUANTUM**2 / 12.0)) if np.isfinite(var) else e


def _base(cell: Cell) -> Cell:
    """The cell with its extensions off (the diagnosis scores each extension from "off")."""
    for key in list(cell.extensions):
        cell = cell.without_extension(key)
    return cell


@dataclass
class Prepared:
    """The data of a diagnosis: the cell (and its base, extensions off), the experiments split into parts, the
    training experiments, the held-out data's name, each file's name and the load warnings."""

    cell: Cell
    base: Cell
    parts: list[Part]
    train: list[Experiment]
    held_name: str
    files: list[str]
    warnings: list[str] = field(default_factory=list)


def prepare(
    data: Sequence[str | Path],
    cell: Cell,
    *,
    held_out: Sequence[str | Path] | None,
    soc0: float | None,
    ambient: Ambient,
    dt: float,
    fix_sign: bool,
    preparations: Sequence[tuple[str | Path, str | Path]] = (),
    full_charge_soc: float = 1.0,
    held_out_tail: bool = False,
) -> Prepared:
    """Load, check and split the data (see the module docstring; ``held_out``: the files to hold out, none for
    the default; ``held_out_tail``: only their final part). ``preparations``: (data file, the log of its
    preparation): the file's first experiment starts at the preparation's full charge, the preparation simulated as
    its unscored lead-in (:func:`battlab.identify.runlog.after_preparation`), from ``full_charge_soc``."""
    from battlab.identify import runlog
    from battlab.identify.experiments import experiments_from_data

    base = _base(cell)
    held_out = tuple(held_out or ())
    paths = [str(p) for p in data]
    paths += [str(h) for h in held_out if not any(str(h) in _file_key(p, Path(p)) for p in paths)]
    check_ambient_keys(paths, ambient)
    loaded, warned = load_all(paths, fix_sign=fix_sign)
    preps = _preparation_logs(preparations, fix_sign)
    hold_names: list[str] = []
    data_parts: list[tuple[str, list[Experiment]]] = []
    for p, d in zip(paths, loaded, strict=True):
        _check_capacity(d, base)
        exps = experiments_from_data(d, base, dt=dt, soc0=soc0, ambient=ambient_of(d, ambient))
        exps = [_measured_noise(e, base) for e in exps]
        if Path(p).resolve() in preps and exps:
            exps[0] = runlog.after_preparation(exps[0], preps[Path(p).resolve()], base, full_charge_soc)
        data_parts.append((d.name, exps))
        if any(str(h) in _file_key(p, d) for h in held_out):
            hold_names.append(d.name)
    parts, held_name = split(data_parts, hold_names, held_out_tail)
    train = [e for e in (p.training() for p in parts) if e is not None]
    if not train:
        raise InputError("diagnose: no training data left (give more than the held-out file)")
    if all(p.train >= p.n for p in parts):
        raise InputError("diagnose: no held-out data (a file given as --held-out must be one of the data)")
    return Prepared(cell, base, parts, train, held_name, [name for name, _ in data_parts], list(warned))


def _preparation_logs(preparations: Sequence[tuple[str | Path, str | Path]], fix_sign: bool) -> dict[Path, Any]:
    """The preparations' logs by their data file's resolved path."""
    if not preparations:
        return {}
    loaded, _ = load_all([str(b) for _, b in preparations], fix_sign=fix_sign)
    return {Path(a).resolve(): d for (a, _), d in zip(preparations, loaded, strict=True)}


def simulate_on(fm: Any, e: Experiment, names: Sequence[str] = ()) -> Any:
    return fm.run(
        fm.theta_of(fm.cell),
        e.profile,
        e.soc0,
        ambient=e.ambient,
        T0=e.T0,
        sensitivities=names,
        sample_delay=e.sample_delay,
    )
