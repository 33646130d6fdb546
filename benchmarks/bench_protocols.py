"""Timings of the protocols package against its targets.

* library build without screening: target <= 10 s (also save/load to HDF5, for information);
* export of a 3600 s profile to every format: target <= 1 s per format. The profile is library id 720 (a
  0.1 Hz sinusoid over 3600 s: 3600 distinct 1 s samples, the most segments of any 3600 s library profile),
  plus the UDDS drive cycle (id 721, 2738 s, no repeats to loop over) for the formats that can hold it.

Run: ``python benchmarks/bench_protocols.py``. Prints a table (best of ``REPEATS`` runs) and, beside it, the
time PyBaMM takes to build its Experiment from the exported module (side by side in this process).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from protocols import Library
from protocols.export import Format, export

REPEATS = 3


def best(fn: Callable[[], object], repeats: int = REPEATS) -> float:
    """Best wall time of ``repeats`` calls [s]."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rows: list[tuple[str, float, float | None]] = []
    t0 = time.perf_counter()
    lib = Library.build()  # first build in this process: includes reading the drive-cycle data
    rows.append(("library build, cold (738 profiles)", time.perf_counter() - t0, 10.0))
    rows.append(("library build, warm", best(Library.build), 10.0))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        rows.append(("library save (HDF5, gzip)", best(lambda: lib.save(out / "lib.h5")), None))
        rows.append(("library load (HDF5)", best(lambda: Library.load(out / "lib.h5")), None))
        for pid in (720, 721):
            p = lib[pid]
            for fmt in Format:
                if pid == 721 and fmt in (Format.ARBIN, Format.BIOLOGIC, Format.NEWARE):
                    continue  # refused: more steps than these formats take (see the exporters)
                target = out / f"{fmt.value}_{pid}"
                t = best(lambda p=p, fmt=fmt, target=target: export(p, fmt, target))
                rows.append((f"export {p.duration:.0f} s profile {pid} -> {fmt.value}", t, 1.0))
        try:
            import pybamm  # noqa: F401

            from protocols.export.pybamm import load_module

            module = load_module(export(lib[720], Format.PYBAMM, out / "pb").path)
            rows.append(("pybamm.Experiment from the export (PyBaMM)", best(module.experiment), None))
        except ImportError:
            pass
    width = max(len(r[0]) for r in rows)
    print(f"{'what':<{width}}  {'time/s':>8}  {'target/s':>8}  ok")
    for name, t, target in rows:
        ok = "" if target is None else ("yes" if t <= target else "NO")
        tgt = "" if target is None else f"{target:.1f}"
        print(f"{name:<{width}}  {t:>8.3f}  {tgt:>8}  {ok}")
    print(f"library: {len(lib)} profiles, {lib.total_hours:.2f} h (paper: 738, 329.65 h)")


if __name__ == "__main__":
    main()
