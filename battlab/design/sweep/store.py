"""The HDF5 sensitivity store: one group per profile, written atomically, keyed so that a killed sweep resumes
and a store made for another cell or model version is refused."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from battlab.cell import Cell
from battlab.design.sweep.keys import (
    CONVENTIONAL,
    FORMAT,
    FORMAT_VERSION,
    GROUP,
    TMP_PREFIX,
    SweepConfig,
    id_value,
    model_source_hash,
    model_version,
    profile_hash,
)
from battlab.design.sweep.task import Outcome
from protocols.errors import InputError
from protocols.profile import Profile

# --- the store ---------------------------------------------------------------------------------------------


def group_name(pid: Any) -> str:
    v = id_value(pid)
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
            for name in [n for n in self.f[where] if n.startswith(TMP_PREFIX)]:
                del self.f[where][name]
        self.f.flush()

    def key(self, pid: int | str, where: str = GROUP) -> str | None:
        g = self.f[where].get(group_name(pid))
        return None if g is None else str(g.attrs["key"])

    def ids(self, status: str | Sequence[str] | None = None, where: str = GROUP) -> list[Any]:
        """Profile ids in the store (optionally only those with this status: ok, flagged, failed)."""
        want = (status,) if isinstance(status, str) else status
        out = []
        for name in self.f[where]:
            if name.startswith(TMP_PREFIX):
                continue
            g = self.f[where][name]
            if want is None or g.attrs["status"] in want:
                out.append(id_value(g.attrs["id"]))
        return out

    def write(self, out: Outcome, profile: Profile, where: str = GROUP) -> None:
        """Write one outcome atomically (temporary group, then rename, then flush)."""
        name = group_name(out.id)
        parent = self.f[where]
        tmp = TMP_PREFIX + name
        if tmp in parent:
            del parent[tmp]
        g = parent.create_group(tmp)
        pid = id_value(profile.id)
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
        d["id"] = id_value(d["id"])
        d["flags"] = json.loads(d.get("flags", "[]"))
        d["params"] = json.loads(d.get("params", "{}"))
        return d

    def _group(self, pid: int | str, where: str = GROUP) -> h5py.Group:
        g = self.f[where].get(group_name(pid))
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
        return Profile(g["t"][()], g["current"][()], id=id_value(g.attrs["id"]))

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
