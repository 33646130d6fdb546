"""Our run log: one HDF5 file per run, appendable in chunks and readable while it is written (h5py SWMR).

Layout (format ``battlab-run-log``, version 1)::

    /            attrs: format, version, columns (JSON list of BDF names), units (JSON list),
                        meta (JSON: cell, protocol/plan, instruments and identities, software, hashes, …),
                        created (ISO 8601 UTC); after a clean close also final (JSON) and rows
    /data        float64 (n_rows, n_columns), chunked, unlimited rows; attrs columns, units (the same lists)
    /gaps        float64 (n_gaps, 3): the row after a gap in sampling, the test times / s of the samples before
                 and after it (attrs columns); read back as ``meta["gaps"]`` (a list of those triples)

One 2-D dataset (not one per column) makes every append atomic for a reader: it never sees columns of different
lengths. The writer switches to SWMR mode after creating the file (``defer_swmr``: at its first flush, so that
:meth:`LogWriter.update_meta` can still complete the metadata), so readers (``read_log``) may open it from then
on; rows appended before the last :meth:`LogWriter.flush` survive a killed writer.

The lab runner writes through::

    w = open_log("run.h5", ["Test Time / s", "Voltage / V", "Current / A", ...], run_meta(...))
    w.append(rows)          # (n, n_columns) array, a sequence of rows, or {column: values}
    w.mark_gaps(marks)      # (n, 3): row after the gap, test time before and after / s
    w.flush()               # make appended rows durable and visible to readers
    w.close(final_meta)     # optional final metadata (e.g. {"ended_by": None, "status": "completed"})
"""

from __future__ import annotations

import datetime as _dt
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from battlab.io.logged import REQUIRED, LoggedData
from protocols.errors import InputError

FORMAT = "battlab-run-log"
VERSION = 1
#: the columns of ``/gaps``
GAP_COLUMNS = ("Row / 1", "Test Time Before / s", "Test Time After / s")


def unit_of(column: str) -> str:
    """The unit part of a BDF column name ('Voltage / V' → 'V'); '' when there is none."""
    return column.rsplit(" / ", 1)[1].strip() if " / " in column else ""


def _json(value: Any) -> str:
    return json.dumps(value, default=_json_default, sort_keys=True)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value of type {type(obj).__name__} is not JSON-serialisable")


def run_meta(
    *,
    cell: Any = None,
    protocol: Any = None,
    plan: Any = None,
    instruments: Mapping[str, Any] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """Standard run metadata: cell name and parameter hash, protocol/plan (as data), instruments, software.

    ``cell``: a :class:`battlab.Cell` (name and hash are stored) or a name; ``protocol``/``plan``: a
    :class:`protocols.Protocol` (stored via ``to_dict``), a mapping or a path; ``instruments``: role →
    identity (e.g. ``{"cycler": {"url": ..., "idn": "..."}}``).
    """
    from battlab import __version__

    meta: dict[str, Any] = {"software": {"battlab": __version__}}
    if cell is not None:
        if hasattr(cell, "hash"):
            meta["cell"] = cell.name
            meta["parameter_hashes"] = {"cell": cell.hash()}
        else:
            meta["cell"] = str(cell)
    for key, value in (("protocol", protocol), ("plan", plan)):
        if value is not None:
            meta[key] = value.to_dict() if hasattr(value, "to_dict") else value
    if instruments is not None:
        meta["instruments"] = dict(instruments)
    meta.update(extra)
    return meta


class LogWriter:
    """Appends rows to a run log (SWMR). Use :func:`open_log` to create one; also a context manager."""

    def __init__(
        self, path: Path, columns: Sequence[str], meta: Mapping[str, Any], chunk_rows: int, defer_swmr: bool = False
    ) -> None:
        import h5py

        self.path = path
        self.columns = tuple(columns)
        self._index = {c: k for k, c in enumerate(self.columns)}
        self._file = h5py.File(path, "w", libver="latest")
        units = [unit_of(c) for c in self.columns]
        f = self._file
        f.attrs["format"] = FORMAT
        f.attrs["version"] = VERSION
        f.attrs["columns"] = _json(list(self.columns))
        f.attrs["units"] = _json(units)
        self._meta = dict(meta)
        f.attrs["meta"] = _json(self._meta)
        f.attrs["created"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        ds = f.create_dataset(
            "data",
            shape=(0, len(self.columns)),
            maxshape=(None, len(self.columns)),
            dtype="f8",
            chunks=(max(int(chunk_rows), 1), len(self.columns)),
        )
        ds.attrs["columns"] = _json(list(self.columns))
        ds.attrs["units"] = _json(units)
        self._ds = ds
        gaps = f.create_dataset("gaps", shape=(0, 3), maxshape=(None, 3), dtype="f8", chunks=(256, 3))
        gaps.attrs["columns"] = _json(list(GAP_COLUMNS))
        self._gaps = gaps
        self._closed = False
        self._swmr = False
        if not defer_swmr:
            self._start_swmr()

    def _start_swmr(self) -> None:
        if not self._swmr:
            self._file.swmr_mode = True
            self._swmr = True

    def update_meta(self, values: Mapping[str, Any]) -> None:
        """Add to or change the run metadata; only before the first flush of a log opened with ``defer_swmr``
        (attributes cannot be written in SWMR mode)."""
        if self._swmr or self._closed:
            raise RuntimeError(f"{self.path}: metadata can only be changed before the log's first flush")
        meta = {**self._meta, **values}
        self._file.attrs["meta"] = _json(meta)
        self._meta = meta

    @property
    def n_rows(self) -> int:
        """Rows appended so far."""
        return int(self._ds.shape[0])

    def append(self, rows: Any) -> None:
        """Append rows: an (n, n_columns) array, a sequence of rows, or a mapping column → values (all columns)."""
        if self._closed:
            raise InputError(f"{self.path}: log is closed")
        if isinstance(rows, Mapping):
            unknown = [c for c in rows if c not in self._index]
            missing = [c for c in self.columns if c not in rows]
            if unknown or missing:
                raise InputError(f"{self.path}: append: unknown column(s) {unknown}, missing column(s) {missing}")
            block = np.column_stack([np.atleast_1d(np.asarray(rows[c], float)) for c in self.columns])
        else:
            block = np.asarray(rows, dtype=float)
            if block.ndim == 1:
                block = block.reshape(1, -1)
        if block.ndim != 2 or block.shape[1] != len(self.columns):
            raise InputError(
                f"{self.path}: append: expected rows of {len(self.columns)} values ({', '.join(self.columns)}), "
                f"got shape {block.shape}"
            )
        if block.shape[0] == 0:
            return
        n = self.n_rows
        self._ds.resize((n + block.shape[0], len(self.columns)))
        self._ds[n:] = block

    def mark_gaps(self, marks: Any) -> None:
        """Record gaps in sampling: rows of (row after the gap, test time before / s, test time after / s)."""
        if self._closed:
            raise InputError(f"{self.path}: log is closed")
        block = np.asarray(marks, dtype=float).reshape(-1, 3)
        if block.shape[0] == 0:
            return
        n = int(self._gaps.shape[0])
        self._gaps.resize((n + block.shape[0], 3))
        self._gaps[n:] = block

    def flush(self) -> None:
        """Make the appended rows durable and visible to SWMR readers."""
        if not self._closed:
            self._start_swmr()
            self._ds.flush()
            self._gaps.flush()
            self._file.flush()

    def close(self, final_meta: Mapping[str, Any] | None = None) -> None:
        """Flush and close; ``final_meta`` (JSON-able) is stored as the ``final`` attribute."""
        if self._closed:
            return
        self.flush()
        n = self.n_rows
        self._file.close()
        self._closed = True
        import h5py

        with h5py.File(self.path, "r+", libver="latest") as f:  # attributes cannot be added in SWMR mode
            f.attrs["rows"] = n
            if final_meta is not None:
                f.attrs["final"] = _json(dict(final_meta))

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close({"status": "error"} if exc[0] is not None else None)


def open_log(
    path: str | Path,
    columns: Sequence[str],
    meta: Mapping[str, Any],
    *,
    chunk_rows: int = 1024,
    defer_swmr: bool = False,
) -> LogWriter:
    """Create a run log at ``path`` with BDF ``columns`` (must include time, voltage, current) and ``meta``.

    An existing file is an error (logged data is never overwritten). ``defer_swmr``: readers may open the log only
    from its first flush on, and :meth:`LogWriter.update_meta` works until then.
    """
    path = Path(path)
    cols = list(columns)
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        raise InputError(f"{path}: a run log needs the columns {list(REQUIRED)}; missing {missing}")
    dup = sorted({c for c in cols if cols.count(c) > 1})
    if dup:
        raise InputError(f"{path}: column(s) {dup} given more than once")
    if path.exists():
        raise InputError(f"{path}: already exists; a run log is never overwritten")
    try:
        _json(dict(meta))
    except TypeError as exc:
        raise InputError(f"{path}: metadata: {exc}") from None
    return LogWriter(path, cols, meta, chunk_rows, defer_swmr)


#: HDF5's signature, at the start of the superblock (offset 0: battlab's logs have no user block)
_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: A SWMR reader retries a metadata read whose checksum fails (the writer may be mid-flush), sleeping 1 ns, 2 ns,
#: 4 ns, …; with HDF5's default of 100 attempts a truncated file never fails. 28 attempts bound the retries of one
#: read at about 0.3 s, ample for a live writer's flush.
SWMR_READ_ATTEMPTS = 28
#: a file shorter than its superblock says is re-checked this often, this far apart / s (a live writer extends the
#: file just after it writes the superblock) before it is called truncated
_TRUNCATION_CHECKS, _TRUNCATION_WAIT_S = 5, 0.05


def _stored_eof(path: Path) -> int | None:
    """The end-of-file address a version 2/3 superblock records (bytes), or None if there is no such superblock
    (not HDF5, or an older superblock version this writer never makes)."""
    with path.open("rb") as fh:
        head = fh.read(48)
    if len(head) < 12 or head[:8] != _SIGNATURE or head[8] not in (2, 3):
        return None
    size = head[9]  # size of offsets / bytes
    if size not in (2, 4, 8) or len(head) < 12 + 4 * size:
        return None
    base = int.from_bytes(head[12 : 12 + size], "little")
    eof = int.from_bytes(head[12 + 2 * size : 12 + 3 * size], "little")
    return base + eof


def _check_not_truncated(path: Path) -> None:
    """Raise InputError when ``path`` is shorter than the end of file its superblock records (a copy cut short, a
    disk that filled up): HDF5 skips that check for SWMR readers and would retry reading the missing metadata."""
    import time

    for attempt in range(_TRUNCATION_CHECKS):
        if attempt:
            time.sleep(_TRUNCATION_WAIT_S)
        eof = _stored_eof(path)
        size = path.stat().st_size
        if eof is None or size >= eof:
            return
    raise InputError(f"{path}: run log truncated: {size} bytes on disk, its HDF5 superblock records {eof}")


def _open_swmr(path: Path) -> Any:
    """``path`` opened read-only as a SWMR reader, with HDF5's metadata read attempts bounded where the library
    allows setting them (``H5Pset_metadata_read_attempts``, reached through h5py's own HDF5)."""
    import ctypes

    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    try:
        fn = ctypes.CDLL(h5py.h5.__file__).H5Pset_metadata_read_attempts
    except (OSError, AttributeError):
        fn = None
    if fn is not None:
        fn.argtypes, fn.restype = [ctypes.c_int64, ctypes.c_uint], ctypes.c_int
        fn(fapl.id, SWMR_READ_ATTEMPTS)
    fid = h5py.h5f.open(str(path).encode(), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ, fapl=fapl)
    return h5py.File(fid)


def read_log(path: str | Path) -> LoggedData:
    """Read a run log (also one still being written, or left by a killed writer) as :class:`LoggedData`.

    ``meta`` holds the run metadata plus ``final`` (if closed cleanly), ``created`` and ``complete`` (bool).
    A truncated or damaged file is an :class:`InputError` naming it, raised within about a second.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such run log")
    _check_not_truncated(path)
    try:
        f = _open_swmr(path)
    except (OSError, RuntimeError, ValueError) as exc:
        raise InputError(f"{path}: not a readable HDF5 file ({_one_line(exc)})") from None
    try:
        with f:
            if f.attrs.get("format") != FORMAT:
                raise InputError(f"{path}: not a battlab run log (attribute format = {f.attrs.get('format')!r})")
            if "data" not in f:
                raise InputError(f"{path}: run log has no /data dataset")
            ds = f["data"]
            ds.refresh()
            block = ds[...]
            columns = json.loads(ds.attrs["columns"])
            meta = json.loads(f.attrs.get("meta", "{}"))
            final = f.attrs.get("final")
            meta["created"] = str(f.attrs.get("created", ""))
            meta["complete"] = "rows" in f.attrs
            meta["gaps"] = []
            if "gaps" in f:  # logs of earlier runners have none
                f["gaps"].refresh()
                meta["gaps"] = f["gaps"][...].tolist()
            if final is not None:
                meta["final"] = json.loads(final)
    except (OSError, RuntimeError, KeyError, ValueError) as exc:
        raise InputError(f"{path}: run log damaged, cannot be read ({_one_line(exc)})") from None
    if block.ndim != 2 or block.shape[1] != len(columns):
        raise InputError(f"{path}: run log /data has shape {block.shape}, expected (rows, {len(columns)})")
    cols = {c: block[:, k] for k, c in enumerate(columns)}
    return LoggedData(path.stem, cols, meta, str(path))


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


__all__ = ["FORMAT", "GAP_COLUMNS", "VERSION", "LogWriter", "open_log", "read_log", "run_meta", "unit_of"]
