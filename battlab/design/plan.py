"""Write the design as a plan (:mod:`battlab.io.plan`): protocol TOML files that the runner, ``battlab export``
and ``battlab fit --plan`` read, plus the design metadata in ``<plan>.summary.json``.

``plan.toml`` is the whole experiment: the selected profiles of group 1, then group 2, … each brought to its start
SOC and rested (:func:`protocols.concatenate`); ``plan.group<k>.toml`` holds group k alone. Profile steps refer to
the library by id (``library_id`` plus the top-level ``library`` file) when the library file beside the store
still holds the very same profiles (checked by hash), else the profiles are written inline. ``Protocol.load``
rejects unknown top-level fields, so the design metadata (groups, parameters, selections, criterion, log det) lives
in the JSON sidecars and in the protocol's ``description``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from battlab.design.groups import GroupDesign
from battlab.design.sweep import SensitivityStore, model_version, profile_hash
from battlab.io.plan import Plan, sidecar_path
from protocols.concatenate import concatenate
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.protocol import ProfileStep, Protocol


@dataclass(frozen=True)
class PlanFiles:
    """Paths written by :func:`write_plan`."""

    plan: Path
    groups: tuple[Path, ...]
    summary: Path
    sidecar: Path


def _library_ref(store: SensitivityStore, profiles: Sequence[Profile], plan_dir: Path) -> tuple[str, Any] | None:
    """(path to write in the plan, the Library) if the library file holds exactly these profiles, else None."""
    lib_path = store.attrs.get("library_path") or ""
    if not lib_path or not Path(lib_path).is_file():
        return None
    from protocols.library import Library

    try:
        lib = Library.load(lib_path)
    except InputError:
        return None
    for p in profiles:
        if p.id not in lib or profile_hash(lib[p.id]) != profile_hash(p):
            return None
    try:
        return os.path.relpath(lib_path, plan_dir), lib
    except ValueError:  # another drive (Windows)
        return str(lib_path), lib


def ocv_table(cell: Any, n: int = 21) -> list[tuple[float, float]]:
    """(SOC, OCV [V]) of ``cell`` at ``n`` SOCs from 0 to 1: the voltages the plan's CCCV steps hold to bring the
    cell to each profile's start SOC (the paper's Table 5 covers 0.2–0.8 only and is another cell's)."""
    socs = np.linspace(0.0, 1.0, n)
    return [(float(s), float(v)) for s, v in zip(socs, np.asarray(cell.ocv(socs), float), strict=True)]


#: [s] the default rest before every profile. The fit starts each profile from rest at the SOC of the rest's last
#: voltage, uniform inside the particles; the true cell's negative particles relax with τ = R_s²/D_s ≈ 4.3 h: after a
#: 0.2-SOC discharge at C/2 and 30 min of rest the profile that follows differs from the uniform start by 0.79 mV
#: RMS (noise-free, profile 541 on nca18650-true), after 2 h by 0.08 mV (the virtual tester's noise there: 0.19 mV).
REST_BEFORE_S = 1800.0


def grouped_protocol(
    name: str,
    groups: Sequence[tuple[int, list[Profile]]],
    description: str,
    ocv_table: Sequence[tuple[float, float]] | None = None,
    noise: Sequence[Profile] = (),
    trials: int = 0,
    rest_before_s: float = REST_BEFORE_S,
) -> Protocol:
    """Concatenate the groups' profiles in order and label each profile step 'group k: profile ID' (the labels
    :func:`battlab.io.plan.design_groups` falls back on). ``ocv_table``: (SOC, OCV) pairs the CCCV steps to each
    profile's start SOC hold to (default: the paper's Table 5). ``noise``, ``trials``: first, each noise profile
    ``trials`` times in a row (each trial brought to its start SOC and rested like any profile), labelled
    'noise: profile ID trial k' (:data:`battlab.identify.runlog.NOISE_LABEL`): the repeated trials that eq. 36
    takes the tester's noise from. ``rest_before_s``: the rest before every profile [s] (:data:`REST_BEFORE_S`)."""
    labels = [f"noise: profile {p.id} trial {k}" for p in noise for k in range(1, trials + 1)]
    flat = [p for p in noise for _ in range(trials)]
    labels += [f"group {g}: profile {p.id}" for g, ps in groups for p in ps]
    flat += [p for _, ps in groups for p in ps]
    kw: dict[str, Any] = {"rest_before_s": rest_before_s}
    if ocv_table is not None:
        kw["ocv_table"] = ocv_table
    proto = concatenate(flat, name=name, **kw).protocol
    steps, k = [], 0
    for st in proto.steps:
        if isinstance(st, ProfileStep):
            st = ProfileStep(st.profile, labels[k])
            k += 1
        steps.append(st)
    return Protocol(proto.name, tuple(steps), proto.limits, proto.capacity_ah, description)


def _write(proto: Protocol, path: Path, library_ref: str | None) -> None:
    import tomli_w

    data = proto.to_dict()
    if library_ref is not None:
        data["library"] = library_ref
        for step in data["steps"]:
            if step["kind"] == "profile":
                pid = step["profile"]["id"]
                step.pop("profile")
                step["library_id"] = int(pid)
    path.write_text(tomli_w.dumps(data))


def summary(designs: Sequence[GroupDesign], criterion: str, solve_seconds: float, **extra: Any) -> dict[str, Any]:
    """The machine-readable summary (docs/file-formats.md § Summaries, plus details)."""
    return {
        "criterion": criterion,
        "groups": [
            {"parameters": d.parameters, "selected": d.selected, "logdet": d.logdet, **d.to_dict()} for d in designs
        ],
        "solve_seconds": solve_seconds,
        **extra,
    }


def write_plan(
    designs: Sequence[GroupDesign],
    store: SensitivityStore,
    out: str | Path,
    *,
    criterion: str,
    solve_seconds: float,
    extra: dict[str, Any] | None = None,
    ocv_table: Sequence[tuple[float, float]] | None = None,
    noise: Sequence[Profile] = (),
    trials: int = 0,
    rest_before_s: float = REST_BEFORE_S,
) -> PlanFiles:
    """Write ``out`` (the whole plan), one TOML per group and the design's summary ``<out>.summary.json``, also as
    ``summary.json`` (the name scripts read; the next command writing one in this directory replaces that copy).
    ``noise``, ``trials``: the repeated noise trials at the start of the whole plan; ``rest_before_s``: the rest
    before every profile (:func:`grouped_protocol`)."""
    out = Path(out)
    if out.suffix.lower() != ".toml":
        raise InputError(f"{out}: the plan is a .toml file")
    out.parent.mkdir(parents=True, exist_ok=True)
    per_group = [(d.index, [store.profile(pid) for pid in d.selected]) for d in designs]
    all_profiles = [p for p in noise for _ in range(trials)] + [p for _, ps in per_group for p in ps]
    found = _library_ref(store, all_profiles, out.parent)
    ref, lib = found if found is not None else (None, None)
    cell = store.attrs["cell_name"]
    desc = (
        f"{criterion}-optimal plan for cell {cell}: "
        + "; ".join(f"group {d.index} ({', '.join(d.new_parameters)}): profiles {d.selected}" for d in designs)
        + f" (design metadata in {sidecar_path(out).name})"
    )
    if noise and trials:
        desc = f"{trials} noise trials of profiles {[p.id for p in noise]}, then the " + desc[0].lower() + desc[1:]
    name = f"OED plan ({criterion}-optimal, {cell})"
    whole = grouped_protocol(name, per_group, desc, ocv_table, noise, trials, rest_before_s)
    _write(whole, out, ref)
    group_paths = []
    for d, (g, ps) in zip(designs, per_group, strict=True):
        gp = out.with_name(f"{out.stem}.group{g}.toml")
        name = f"OED group {g} ({criterion}-optimal, {cell})"
        desc_g = f"group {g}: {d.parameters}"
        _write(grouped_protocol(name, [(g, ps)], desc_g, ocv_table, rest_before_s=rest_before_s), gp, ref)
        group_paths.append(gp)
    _check_round_trip(out, all_profiles, lib)
    data = summary(
        designs,
        criterion,
        solve_seconds,
        cell=cell,
        cell_hash=store.attrs["cell_hash"],
        model_version=model_version(),
        store=str(store.path),
        plan=str(out),
        group_plans=[str(p) for p in group_paths],
        library=ref,
        **(extra or {}),
    )
    text = json.dumps(_jsonable(data), indent=1)
    sp = sidecar_path(out)  # the summary is the sidecar that design_groups reads back
    sp.write_text(text)
    out.with_name("summary.json").write_text(text)  # the name scripts read (docs/file-formats.md)
    return PlanFiles(out, tuple(group_paths), sp, sp)


def add_to_summary(files: PlanFiles, **entries: Any) -> None:
    """Add ``entries`` to the design's summary (``<plan>.summary.json`` and its ``summary.json`` copy)."""
    data = json.loads(files.summary.read_text())
    data.update(_jsonable(entries))
    text = json.dumps(data, indent=1)
    files.summary.write_text(text)
    files.plan.with_name("summary.json").write_text(text)


def _check_round_trip(path: Path, profiles: Sequence[Profile], library: Any = None) -> None:
    """The plan must load as a plan (:meth:`battlab.io.plan.Plan.load`) and carry exactly the selected profiles."""
    proto = Plan.load(path, library=library).protocol
    got = [s.profile for s in proto.steps if isinstance(s, ProfileStep)]
    if len(got) != len(profiles) or any(
        profile_hash(a.with_meta(soc0=b.soc0)) != profile_hash(b) for a, b in zip(got, profiles, strict=True)
    ):
        raise RuntimeError(f"{path}: the written plan does not reproduce the selected profiles")  # a bug, not input


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x
