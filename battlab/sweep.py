"""The library sensitivity sweep (issue 4, step 1): every profile simulated with all 18 sensitivities, stored in HDF5.

Each library profile is simulated from its start SOC with the voltage and surface-temperature sensitivities
w.r.t. the normalised parameters θ̄ (eq. 1); the constraint screen (:mod:`battlab.screening`: T_surface ≤ 50 °C,
voltage window, stoichiometry) flags it, a simulation that fails is recorded with its reason. The store holds one
group per profile (``/profiles/0339``), written atomically (a temporary group renamed when complete, then a flush)
so a killed sweep resumes where it stopped. Every group carries a key: the SHA-256 of the cell's parameters
(``Cell.hash``), the profile (its t and current), the model version (``battlab.__version__`` and
:data:`MODEL_VERSION`), the model's source files and the sweep settings; a group whose key differs is stale and
recomputed, and a store made for another cell or model version is refused with the reason.

The Fisher information (eqs. 22, 25) uses the voltage at 1 s sampling: the profile's own samples are all kept
(pulse edges at half seconds too), and the rows at whole seconds feed ``R``, the triangular factor of the
unweighted sensitivity matrix S (Sᵀ S = Rᵀ R), which is all that identifiability and design need.

Runs on local processes (``workers``) or on a Dask distributed cluster (``scheduler``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

import battlab
from battlab import parameters
from battlab.cell import Cell
from battlab.model.mesh import Mesh
from battlab.screening import Limits, constraint_flags, is_solver_failure
from protocols.errors import InputError
from protocols.profile import Profile

MODEL_VERSION = "dfn-thermal-1"
"""Version of the model's equations and numerics as far as stored sensitivities are concerned: bump it when a
change of the model makes old stores wrong (the source hash catches every change, this one says it matters)."""

FORMAT = "battlab-sensitivity"
FORMAT_VERSION = 1
GROUP = "profiles"
CONVENTIONAL = "conventional"
_TMP = "_partial_"


def model_version() -> str:
    """``battlab <version> / <MODEL_VERSION>``: stores with another value are refused."""
    return f"battlab {battlab.__version__} / {MODEL_VERSION}"


def model_source_hash() -> str:
    """SHA-256 of the model's source (``battlab/model``, ``simulation.py``, ``parameters.py``)."""
    root = Path(battlab.__file__).parent
    files = sorted((root / "model").glob("*.py")) + sorted((root / "model").glob("*.c"))
    files += [root / "simulation.py", root / "parameters.py"]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def profile_hash(profile: Profile) -> str:
    """SHA-256 of a profile's samples (t [s], current [A], as float64) and its start SOC."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(profile.t, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(profile.current, dtype="<f8").tobytes())
    h.update(repr(None if profile.soc0 is None else float(profile.soc0)).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class SweepConfig:
    """What is computed: parameters (θ̄ names), ambient [K], thermal option, mesh, screen limits."""

    names: tuple[str, ...] = parameters.NAMES
    ambient: float = 298.15
    isothermal: bool = False
    mesh: Mesh = field(default_factory=Mesh)
    limits: Limits = field(default_factory=Limits)

    def to_json(self) -> str:
        return json.dumps(
            {
                "names": list(self.names),
                "ambient": self.ambient,
                "isothermal": self.isothermal,
                "mesh": asdict(self.mesh),
                "limits": asdict(self.limits),
            },
            sort_keys=True,
        )

    @classmethod
    def from_json(cls, text: str) -> SweepConfig:
        d = json.loads(text)
        return cls(tuple(d["names"]), d["ambient"], d["isothermal"], Mesh(**d["mesh"]), Limits(**d["limits"]))


def result_key(
    cell_hash: str, prof_hash: str, config: SweepConfig, source_hash: str, extend_rest_s: float = 0.0
) -> str:
    """The key of one stored result: any change of cell, profile, model or settings changes it."""
    parts = [cell_hash, prof_hash, model_version(), source_hash, config.to_json(), repr(float(extend_rest_s))]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _id_value(pid: Any) -> int | str:
    """Library ids are integers; conventional tests are named."""
    return int(pid) if isinstance(pid, int | np.integer) or str(pid).isdigit() else str(pid)


# --- the per-profile task (runs in a worker) ---------------------------------------------------------------


@dataclass
class Task:
    """One simulation: the profile's samples, the cell as its TOML dict, the settings (all picklable: profiles
    and cells hold mapping proxies, which do not pickle).

    ``extend_rest_s`` > 0 (conventional tests): run until a limit stops the profile, then cut it there and
    append this much rest [s] (the relaxation is part of the measurement).
    """

    key: str
    pid: int | str
    t: np.ndarray
    current: np.ndarray
    soc0: float | None
    cell_dict: dict[str, Any]
    config: SweepConfig
    extend_rest_s: float = 0.0

    @classmethod
    def of(cls, key: str, p: Profile, cell_dict: dict[str, Any], config: SweepConfig, rest: float = 0.0) -> Task:
        return cls(key, _id_value(p.id), p.t, p.current, p.soc0, cell_dict, config, rest)

    @property
    def profile(self) -> Profile:
        return Profile(self.t, self.current, id=self.pid, soc0=self.soc0)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


@dataclass
class Outcome:
    """What a worker returns for one profile. status: "ok", "flagged" (screen) or "failed" (with reason)."""

    id: int | str
    key: str
    status: str
    reason: str | None = None
    flags: list[str] = field(default_factory=list)
    ended_by: str | None = None
    t: np.ndarray | None = None
    current: np.ndarray | None = None
    voltage: np.ndarray | None = None
    T_surface: np.ndarray | None = None
    sens_V: np.ndarray | None = None
    sens_T: np.ndarray | None = None
    index_1s: np.ndarray | None = None
    R: np.ndarray | None = None
    seconds: float = 0.0


_CELLS: dict[str, Cell] = {}


def _cell_from(d: dict[str, Any]) -> Cell:
    blob = json.dumps(d, sort_keys=True, default=str)
    if blob not in _CELLS:
        _CELLS[blob] = Cell._from_toml_dict(d, str(d.get("name", "cell")))
    return _CELLS[blob]


def one_second_rows(t: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Indices of the samples at whole seconds from the start (the Fisher information's 1 s sampling)."""
    rel = np.asarray(t, float) - float(t[0])
    return np.flatnonzero(np.abs(rel - np.round(rel)) <= tol).astype(np.int64)


def resample_1s(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) at whole seconds from the start: selected when every second is a sample, else interpolated."""
    t = np.asarray(t, float)
    grid = t[0] + np.arange(int(np.floor(t[-1] - t[0] + 1e-9)) + 1)
    rows = one_second_rows(t)
    if rows.size == grid.size:
        return t[rows], np.asarray(y)[rows]
    y2 = np.asarray(y, float).reshape(t.size, -1)
    out = np.column_stack([np.interp(grid, t, y2[:, j]) for j in range(y2.shape[1])])
    return grid, out.reshape((grid.size, *np.asarray(y).shape[1:]))


def triangular_factor(S: np.ndarray) -> np.ndarray:
    """R (p × p, upper triangular) with Rᵀ R = Sᵀ S, from a Householder QR of S (n × p)."""
    S = np.asarray(S, float)
    p = S.shape[1]
    if S.shape[0] < p:
        S = np.vstack([S, np.zeros((p - S.shape[0], p))])
    return np.linalg.qr(S, mode="r")


def run_task(task: Task) -> Outcome:
    """Simulate one profile with sensitivities and screen it (pure: safe in any worker process)."""
    from battlab.simulation import simulate

    t0 = time.perf_counter()
    prof = task.profile
    pid = task.pid
    try:
        cell = _cell_from(task.cell_dict)
        cfg = task.config
        window = cfg.limits.window(cell)
        kw = dict(ambient=cfg.ambient, isothermal=cfg.isothermal, mesh=cfg.mesh, v_limits=window)
        if task.extend_rest_s > 0:
            prof = _cut_and_rest(cell, prof, task.extend_rest_s, kw)
        res = simulate(cell, prof, sensitivities=list(cfg.names), **kw)
    except Exception as exc:  # recorded with the reason, never dropped
        return Outcome(pid, task.key, "failed", f"{type(exc).__name__}: {exc}", seconds=time.perf_counter() - t0)
    out = Outcome(pid, task.key, "ok", ended_by=res.ended_by, seconds=0.0)
    out.t, out.current = res.t, res.current
    out.voltage, out.T_surface = res.voltage, res.T_surface
    out.sens_V, out.sens_T = res.sensitivities, res.sensitivities_T
    usable = res.t.size >= 2 and res.sensitivities is not None and bool(np.all(np.isfinite(res.sensitivities)))
    if is_solver_failure(res.ended_by):
        out.status, out.reason = "failed", res.ended_by
        return _timed(out, t0)
    out.flags = constraint_flags(res, cfg.limits, window)
    if out.flags:
        out.status, out.reason = "flagged", "; ".join(out.flags)
    elif not usable:
        out.status, out.reason = "failed", "no finite sensitivities"
    if usable:
        out.index_1s = one_second_rows(res.t)
        out.R = triangular_factor(res.sensitivities[out.index_1s])
    return _timed(out, t0)


def _timed(out: Outcome, t0: float) -> Outcome:
    out.seconds = time.perf_counter() - t0
    return out


def _cut_and_rest(cell: Cell, prof: Profile, rest_s: float, kw: dict[str, Any]) -> Profile:
    """The profile up to where a limit stops it (whole seconds), followed by ``rest_s`` of rest."""
    from battlab.simulation import simulate

    probe = simulate(cell, prof, **kw)
    if is_solver_failure(probe.ended_by):
        raise RuntimeError(f"probe run failed: {probe.ended_by}")
    t_end = float(np.floor(probe.t[-1] - prof.t[0])) if probe.ended_by else prof.duration
    if t_end < 1.0:
        raise RuntimeError(f"{probe.ended_by} at the start")
    keep = prof.t - prof.t[0] < t_end - 1e-9
    t = np.concatenate([prof.t[keep] - prof.t[0], [t_end], t_end + np.arange(1.0, rest_s + 0.5)])
    i = np.concatenate([prof.current[keep], np.zeros(t.size - int(keep.sum()))])
    return Profile(t, i, id=prof.id, kind=prof.kind, soc0=prof.soc0, params=dict(prof.params))


# --- the store ---------------------------------------------------------------------------------------------


def _gname(pid: Any) -> str:
    v = _id_value(pid)
    return f"{v:04d}" if isinstance(v, int) else v.replace("/", "_")


_BIG = dict(compression="gzip", compression_opts=1, shuffle=True)


class SensitivityStore:
    """An HDF5 sensitivity store (one group per profile under ``/profiles``, conventional tests under
    ``/conventional``). Open for reading with :meth:`open`; the sweep creates or resumes one with :meth:`create`."""

    def __init__(self, path: Path, f: h5py.File) -> None:
        self.path, self.f = path, f

    # --- opening ------------------------------------------------------------------------------------------

    @classmethod
    def create(
        cls, path: str | Path, cell: Cell, config: SweepConfig, *, library_path: str | None = None
    ) -> SensitivityStore:
        """Create the store, or reopen it to resume; refuse one made for another cell, model or parameter set."""
        path = Path(path)
        if path.exists():
            store = cls._open(path, "a")
            problems = store.mismatch(cell, config)
            if problems:
                store.close()
                raise InputError(
                    f"{path}: refusing to add to this sensitivity store: {'; '.join(problems)} "
                    "(write to a new file, or delete this one)"
                )
            store._drop_partials()
            return store
        path.parent.mkdir(parents=True, exist_ok=True)
        f = h5py.File(path, "w")
        f.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "model_version": model_version(),
                "model_source_hash": model_source_hash(),
                "cell_name": cell.name,
                "cell_hash": cell.hash(),
                "cell": json.dumps(cell.to_toml_dict(), default=str),
                "config": config.to_json(),
                "library_path": str(Path(library_path).resolve()) if library_path else "",
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            }
        )
        f.create_group(GROUP)
        f.create_group(CONVENTIONAL)
        f.flush()
        return cls(path, f)

    @classmethod
    def open(cls, path: str | Path, *, check_model: bool = True) -> SensitivityStore:
        """Open a store for reading; one made by another model version is refused (``check_model``)."""
        store = cls._open(Path(path), "r")
        made_by = store.attrs["model_version"]
        if check_model and made_by != model_version():
            store.close()
            raise InputError(
                f"{path}: made by {made_by!r}, this is {model_version()!r}: "
                "its sensitivities are stale; rerun `battlab sensitivity`"
            )
        return store

    @classmethod
    def _open(cls, path: Path, mode: str) -> SensitivityStore:
        if not path.is_file():
            raise InputError(f"{path}: no such sensitivity store")
        try:
            f = h5py.File(path, mode)
        except OSError as exc:
            raise InputError(
                f"{path}: cannot open as HDF5 ({exc}); if a sweep was killed while writing, delete the file and rerun"
            ) from None
        if f.attrs.get("format") != FORMAT:
            f.close()
            raise InputError(f"{path}: not a battlab sensitivity store (no format attribute {FORMAT!r})")
        if int(f.attrs.get("format_version", -1)) != FORMAT_VERSION:
            v = f.attrs.get("format_version")
            f.close()
            raise InputError(f"{path}: store format version {v}, this battlab reads {FORMAT_VERSION}")
        return cls(path, f)

    def mismatch(self, cell: Cell, config: SweepConfig) -> list[str]:
        """Why this store cannot take results for ``cell``/``config`` (empty: it can)."""
        a = self.attrs
        out = []
        if a["cell_hash"] != cell.hash():
            out.append(
                f"it holds cell {a['cell_name']!r} (parameter hash {a['cell_hash'][:12]}), "
                f"not {cell.name!r} (hash {cell.hash()[:12]})"
            )
        if a["model_version"] != model_version():
            out.append(f"it was made by {a['model_version']!r}, this is {model_version()!r}")
        if a["config"] != config.to_json():
            out.append(f"its settings differ ({a['config']} vs {config.to_json()})")
        return out

    def close(self) -> None:
        self.f.close()

    def __enter__(self) -> SensitivityStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- metadata -----------------------------------------------------------------------------------------

    @property
    def attrs(self) -> dict[str, Any]:
        return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in self.f.attrs.items()}

    @property
    def names(self) -> tuple[str, ...]:
        return SweepConfig.from_json(self.attrs["config"]).names

    @property
    def config(self) -> SweepConfig:
        return SweepConfig.from_json(self.attrs["config"])

    def cell(self) -> Cell:
        """The cell the store was computed for."""
        return Cell._from_toml_dict(json.loads(self.attrs["cell"]), self.attrs["cell_name"])

    def source_changed(self) -> bool:
        """True when the model's source files differ from the ones the store was made with."""
        return self.attrs["model_source_hash"] != model_source_hash()

    # --- groups -------------------------------------------------------------------------------------------

    def _drop_partials(self) -> None:
        for where in (GROUP, CONVENTIONAL):
            for name in [n for n in self.f[where] if n.startswith(_TMP)]:
                del self.f[where][name]
        self.f.flush()

    def key(self, pid: int | str, where: str = GROUP) -> str | None:
        g = self.f[where].get(_gname(pid))
        return None if g is None else str(g.attrs["key"])

    def ids(self, status: str | Sequence[str] | None = None, where: str = GROUP) -> list[Any]:
        """Profile ids in the store (optionally only those with this status: ok, flagged, failed)."""
        want = (status,) if isinstance(status, str) else status
        out = []
        for name in self.f[where]:
            if name.startswith(_TMP):
                continue
            g = self.f[where][name]
            if want is None or g.attrs["status"] in want:
                out.append(_id_value(g.attrs["id"]))
        return out

    def write(self, out: Outcome, profile: Profile, where: str = GROUP) -> None:
        """Write one outcome atomically (temporary group, then rename, then flush)."""
        name = _gname(out.id)
        parent = self.f[where]
        tmp = _TMP + name
        if tmp in parent:
            del parent[tmp]
        g = parent.create_group(tmp)
        pid = _id_value(profile.id)
        g.attrs.update(
            {
                "id": pid,
                "key": out.key,
                "status": out.status,
                "reason": out.reason or "",
                "flags": json.dumps(out.flags),
                "ended_by": out.ended_by or "",
                "seconds": out.seconds,
                "kind": profile.kind or "",
                "soc0": np.nan if profile.soc0 is None else float(profile.soc0),
                "params": json.dumps(dict(profile.params), default=str),
                "profile_hash": profile_hash(profile),
                "duration": profile.duration,
            }
        )
        g.create_dataset("profile_t", data=profile.t)
        g.create_dataset("profile_current", data=profile.current)
        if out.t is not None and out.voltage is not None:
            n = out.t.size
            g.create_dataset("t", data=out.t)
            g.create_dataset("current", data=out.current)
            g.create_dataset("voltage", data=out.voltage)
            g.create_dataset("T_surface", data=out.T_surface)
            for nm, arr in (("sens_V", out.sens_V), ("sens_T", out.sens_T)):
                if arr is not None and n:
                    g.create_dataset(nm, data=np.asarray(arr, np.float32), chunks=(min(n, 4096), arr.shape[1]), **_BIG)
            if out.index_1s is not None:
                g.create_dataset("index_1s", data=out.index_1s.astype(np.int32))
            if out.R is not None:
                g.create_dataset("R", data=out.R)
            g.attrs["T_surface_max_C"] = float(np.max(out.T_surface)) - 273.15 if n else np.nan
            g.attrs["simulated_s"] = float(out.t[-1] - out.t[0]) if n else 0.0
        if name in parent:
            del parent[name]
        parent.move(tmp, name)
        self.f.flush()

    def info(self, pid: int | str, where: str = GROUP) -> dict[str, Any]:
        """Attributes of one profile's group (status, reason, flags, kind, soc0, params, …)."""
        g = self._group(pid, where)
        d = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in g.attrs.items()}
        d["id"] = _id_value(d["id"])
        d["flags"] = json.loads(d.get("flags", "[]"))
        d["params"] = json.loads(d.get("params", "{}"))
        return d

    def _group(self, pid: int | str, where: str = GROUP) -> h5py.Group:
        g = self.f[where].get(_gname(pid))
        if g is None:
            raise InputError(f"{self.path}: no profile {pid} in /{where}")
        return g

    def profile(self, pid: int | str, where: str = GROUP) -> Profile:
        """The profile as it was simulated."""
        g = self._group(pid, where)
        a = self.info(pid, where)
        soc0 = float(a["soc0"])
        return Profile(
            g["profile_t"][()],
            g["profile_current"][()],
            id=a["id"],
            kind=a["kind"] or None,
            soc0=None if np.isnan(soc0) else soc0,
            params=a["params"],
        )

    def simulated_profile(self, pid: int | str, where: str = GROUP) -> Profile:
        """The current as simulated (a conventional test cut at its limit plus its rest; a flagged profile up to
        where it stopped)."""
        g = self._group(pid, where)
        if "t" not in g or g["t"].size < 2:
            return self.profile(pid, where)
        return Profile(g["t"][()], g["current"][()], id=_id_value(g.attrs["id"]))

    def R(self, pid: int | str, where: str = GROUP) -> np.ndarray:
        """Triangular factor of the unweighted 1 s voltage sensitivities (Rᵀ R = Sᵀ S), p × p."""
        g = self._group(pid, where)
        if "R" not in g:
            raise InputError(
                f"{self.path}: profile {pid} has no sensitivities ({g.attrs['status']}: {g.attrs['reason']})"
            )
        return g["R"][()]

    def trajectory(self, pid: int | str, where: str = GROUP) -> dict[str, np.ndarray]:
        """t, current, voltage, T_surface, sens_V, sens_T (all samples of the profile)."""
        g = self._group(pid, where)
        return {k: g[k][()] for k in ("t", "current", "voltage", "T_surface", "sens_V", "sens_T", "index_1s") if k in g}

    def statuses(self, where: str = GROUP) -> dict[Any, str]:
        return {pid: str(self._group(pid, where).attrs["status"]) for pid in self.ids(where=where)}


# --- the sweep ---------------------------------------------------------------------------------------------


@dataclass
class SweepReport:
    """Counts and timing of a sweep (``computed`` this run, ``reused`` from the store)."""

    path: Path
    total: int = 0
    reused: int = 0
    computed: int = 0
    ok: int = 0
    flagged: int = 0
    failed: int = 0
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0
    failures: dict[Any, str] = field(default_factory=dict)
    flags: dict[Any, str] = field(default_factory=dict)


Executor = Callable[[Sequence[Task]], Iterator[Outcome]]


def local_executor(workers: int) -> Executor:
    """Run tasks on ``workers`` local processes (1: in this process), at most a few in flight per worker so that
    memory stays bounded (results are written and dropped as they arrive)."""

    def run(tasks: Sequence[Task]) -> Iterator[Outcome]:
        if workers <= 1:
            for task in tasks:
                yield run_task(task)
            return
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("forkserver")) as pool:
            yield from _windowed(pool.submit, tasks, 3 * workers, wait_any=_wait_local)

    return run


def _wait_local(pending: set) -> tuple[set, set]:
    from concurrent.futures import FIRST_COMPLETED, wait

    done, rest = wait(pending, return_when=FIRST_COMPLETED)
    return set(done), set(rest)


def _windowed(submit: Callable[..., Any], tasks: Sequence[Task], window: int, wait_any: Callable) -> Iterator[Outcome]:
    """Submit ``tasks`` in order keeping at most ``window`` in flight; yield outcomes as they complete."""
    it = iter(tasks)
    pending: dict[Any, Task] = {}
    for task in it:
        pending[submit(run_task, task)] = task
        if len(pending) >= window:
            break
    while pending:
        done, _ = wait_any(set(pending))
        for fut in done:
            task = pending.pop(fut)
            yield _outcome_of(fut, task)
            nxt = next(it, None)
            if nxt is not None:
                pending[submit(run_task, nxt)] = nxt


def dask_executor(scheduler: str | Any, timeout_s: float = 10.0) -> Executor:
    """Run tasks on a Dask distributed cluster (a scheduler address like ``tcp://host:8786`` or a Client)."""

    def run(tasks: Sequence[Task]) -> Iterator[Outcome]:
        from dask.distributed import Client, wait

        own = not isinstance(scheduler, Client)
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s") if own else scheduler
        except OSError as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            n = max(sum(client.nthreads().values()), 1)

            def submit(fn: Callable, task: Task) -> Any:
                return client.submit(fn, task, pure=False, key=f"battlab-sweep-{task.key[:16]}-{task.pid}")

            def wait_any(pending: set) -> tuple[set, set]:
                res = wait(list(pending), return_when="FIRST_COMPLETED")
                return set(res.done), set(res.not_done)

            yield from _windowed(submit, tasks, 3 * n, wait_any=wait_any)
        finally:
            if own:
                client.close()

    return run


def _outcome_of(fut: Any, task: Task) -> Outcome:
    try:
        return fut.result()
    except Exception as exc:  # the worker died or the task could not be shipped: record, do not drop
        return Outcome(task.pid, task.key, "failed", f"worker error: {type(exc).__name__}: {exc}")


def select_profiles(
    profiles: Iterable[Profile], ids: Sequence[int] | None = None, limit: int | None = None
) -> list[Profile]:
    """The profiles to sweep: those with the given ids (all if None), then the first ``limit``."""
    profs = list(profiles)
    if ids:
        have = {int(p.id): p for p in profs}  # type: ignore[arg-type]
        missing = [i for i in ids if int(i) not in have]
        if missing:
            raise InputError(f"no profile(s) with id {missing} in the library (ids run {min(have)}..{max(have)})")
        profs = [have[int(i)] for i in ids]
    if limit is not None:
        if limit < 1:
            raise InputError(f"--limit must be at least 1, got {limit}")
        profs = profs[:limit]
    return profs


def sweep(
    profiles: Iterable[Profile],
    cell: Cell,
    out: str | Path,
    *,
    config: SweepConfig | None = None,
    workers: int | None = None,
    scheduler: str | Any | None = None,
    conventional: Sequence[Profile] = (),
    conventional_rest_s: float = 3600.0,
    library_path: str | None = None,
    progress: bool = True,
    on_written: Callable[[Outcome], None] | None = None,
    connect_timeout_s: float = 10.0,
) -> SweepReport:
    """Simulate every profile (and the conventional tests) with sensitivities into the store ``out``.

    Resumes: profiles whose stored key matches are reused; failed ones are retried. ``workers``: local
    processes (default: all cores); ``scheduler``: a Dask scheduler address or Client instead. ``on_written``
    is called after each profile is on disk (tests use it to kill the process mid-sweep).
    """
    t_wall = time.perf_counter()
    config = config or SweepConfig()
    profs = list(profiles)
    if not profs and not conventional:
        raise InputError("no profiles to sweep")
    for p in profs:
        if p.id is None or not str(p.id).isdigit():
            raise InputError(f"library profiles need integer ids, got {p.id!r}")
    store = SensitivityStore.create(out, cell, config, library_path=library_path)
    report = SweepReport(Path(out), total=len(profs) + len(conventional))
    try:
        src, ch, cd = model_source_hash(), cell.hash(), cell.to_toml_dict()
        tasks: list[tuple[Task, str, Profile]] = []
        for where, items, rest in ((GROUP, profs, 0.0), (CONVENTIONAL, list(conventional), conventional_rest_s)):
            for p in items:
                key = result_key(ch, profile_hash(p), config, src, rest)
                g = store.f[where].get(_gname(p.id))
                if g is not None and g.attrs["key"] == key and g.attrs["status"] != "failed":
                    report.reused += 1
                    continue
                tasks.append((Task.of(key, p, cd, config, rest), where, p))
        tasks.sort(key=lambda tw: -tw[0].duration - (1e6 if tw[1] == CONVENTIONAL else 0))  # longest first
        by_key = {(t.key, str(t.pid)): (w, p) for t, w, p in tasks}
        if tasks and scheduler is None:
            _warm(cell, config)
        ex = (
            dask_executor(scheduler, connect_timeout_s)
            if scheduler is not None
            else local_executor(workers or os.cpu_count() or 1)
        )
        with _progress(progress, len(tasks), report.reused) as advance:
            for outcome in ex([t for t, _, _ in tasks]):
                where, prof = by_key[(outcome.key, str(outcome.id))]
                store.write(outcome, prof, where)
                report.computed += 1
                report.cpu_seconds += outcome.seconds
                if on_written is not None:
                    on_written(outcome)
                advance(outcome)
        for where in (GROUP, CONVENTIONAL):
            for pid, status in store.statuses(where).items():
                if where == GROUP and str(pid) not in {str(p.id) for p in profs}:
                    continue
                info = store.info(pid, where)
                if status == "ok":
                    report.ok += 1
                elif status == "flagged":
                    report.flagged += 1
                    report.flags[pid] = info["reason"]
                else:
                    report.failed += 1
                    report.failures[pid] = info["reason"]
        report.wall_seconds = time.perf_counter() - t_wall
        store.f.attrs["last_sweep"] = json.dumps(
            {
                k: v
                for k, v in asdict(report).items()
                if k in ("total", "reused", "computed", "ok", "flagged", "failed", "wall_seconds", "cpu_seconds")
            }
        )
        store.f.flush()
    finally:
        store.close()
    return report


def _warm(cell: Cell, config: SweepConfig) -> None:
    """Build (or load from the disk cache) the compiled stepper once before workers start, so they only load it."""
    from battlab.model import solver

    with contextlib.suppress(Exception):  # the workers then fall back to the CasADi stepper and say so
        solver.native_stepper(cell, config.mesh, config.isothermal)


class _progress:
    """A rich progress bar (or nothing) whose ``advance(outcome)`` counts ok / flagged / failed."""

    def __init__(self, enabled: bool, total: int, reused: int) -> None:
        self.enabled, self.total, self.reused = enabled, total, reused
        self.counts = {"ok": 0, "flagged": 0, "failed": 0}

    def __enter__(self) -> Callable[[Outcome], None]:
        if not self.enabled:
            return lambda o: None
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.bar = Progress(
            TextColumn("sensitivities"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            TextColumn("{task.description}"),
        )
        self.bar.start()
        self.task = self.bar.add_task(f"({self.reused} reused)", total=self.total)

        def advance(o: Outcome) -> None:
            self.counts[o.status] = self.counts.get(o.status, 0) + 1
            c = self.counts
            self.bar.update(
                self.task,
                advance=1,
                description=f"ok {c['ok']} flagged {c['flagged']} failed {c['failed']} ({self.reused} reused)",
            )

        return advance

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self.bar.stop()
