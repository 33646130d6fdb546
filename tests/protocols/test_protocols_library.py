"""The input library: counts, constraints on every profile, stable ids, HDF5, screening."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from protocols import InputError, Library, Profile
from protocols.constants import START_SOCS
from protocols.library import soc_window_ok

C = 2.7


def test_counts_after_each_filter(lib: Library) -> None:
    got = [(c.filter, c.pulse, c.sine, c.drive) for c in lib.counts]
    assert got == [
        ("grid", 1008, 216, 24),
        ("fits", 816, 216, 24),
        ("duration", 816, 216, 24),
        ("current", 648, 216, 24),
        ("soc_window", 540, 180, 18),
    ]
    assert lib.kind_counts() == {"pulse": 540, "sine": 180, "drive": 18}
    assert len(lib) == 738


def test_every_profile_meets_the_constraints(lib: Library) -> None:
    for p in lib:
        where = f"profile {p.id}"
        assert p.charge_throughput == pytest.approx(1.0, abs=1e-9), where
        assert p.max_abs_current <= 5 * C * (1 + 1e-12), where
        assert 600.0 <= p.duration <= 3600.0, where
        assert p.soc0 in START_SOCS, where
        soc = p.soc(C)
        assert soc.min() >= -1e-12 and soc.max() <= 1 + 1e-12, where
        if p.soc0 == 0.2:
            assert p.net_charge >= -1e-9, where
        if p.soc0 == 0.8:
            assert p.net_charge <= 1e-9, where
        dt = np.diff(p.t)
        assert dt.max() <= 1.0 + 1e-12, where  # 1 s sampling, finer only at pulse edges
        assert np.allclose(p.t * 2, np.round(p.t * 2)), where  # edges on half-second samples


def test_ids_follow_the_documented_order(lib: Library) -> None:
    assert lib.ids == list(range(1, 739))
    kinds = [p.kind for p in lib]
    assert kinds == ["pulse"] * 540 + ["sine"] * 180 + ["drive"] * 18
    for kind in ("pulse", "sine", "drive"):
        socs = [p.soc0 for p in lib.select(kind=kind)]
        assert socs == sorted(socs, reverse=True)
    first = lib[1].params
    assert (first["width_s"], first["total_s"], first["rest_factor"], first["direction"]) == (
        1.0,
        600.0,
        1,
        "discharge",
    )
    assert [p.params["cycle"] for p in lib.select(kind="drive", soc0=0.8)] == [
        "udds",
        "us06",
        "hwfet",
        "wltc3b",
        "dc1",
        "dc2",
    ]


def test_pulse_amplitudes_span_the_papers_range(lib: Library) -> None:
    amps = [p.max_abs_current / C for p in lib.select(kind="pulse")]
    assert min(amps) == pytest.approx(1.8 / C)  # 1 Ah over 2000 s of on-time (w = 1000 s, n = 1)
    assert max(amps) <= 5.0 and max(amps) > 4.4


def _index_rows(lib: Library) -> list[dict[str, str]]:
    rows = []
    for p in lib:
        rows.append(
            {
                "id": str(p.id),
                "kind": str(p.kind),
                "soc0": f"{p.soc0:g}",
                "name": str(p.params["name"]),
                "samples": str(p.t.size),
                "duration_s": f"{p.duration:.10g}",
                "max_abs_a": f"{p.max_abs_current:.10g}",
                "net_ah": f"{p.net_charge:.10g}",
            }
        )
    return rows


def test_ids_are_stable_against_the_checked_in_index(lib: Library, golden: Path, regenerate: bool) -> None:
    """Same id => same profile in every build (the index was written by this code and checked in)."""
    path = golden / "library_index.csv"
    rows = _index_rows(lib)
    if regenerate:
        with path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    with path.open(newline="") as fh:
        ref = list(csv.DictReader(fh))
    assert len(ref) == len(rows)
    for a, b in zip(ref, rows, strict=True):
        assert (a["id"], a["kind"], a["soc0"], a["name"], a["samples"]) == (
            b["id"],
            b["kind"],
            b["soc0"],
            b["name"],
            b["samples"],
        )
        for key in ("duration_s", "max_abs_a", "net_ah"):
            assert float(a[key]) == pytest.approx(float(b[key]), rel=1e-8, abs=1e-12), (a["id"], key)


def test_two_builds_are_identical(lib: Library) -> None:
    again = Library.build()
    for p, q in zip(lib, again, strict=True):
        assert p.id == q.id and dict(p.params) == dict(q.params)
        np.testing.assert_array_equal(p.t, q.t)
        np.testing.assert_array_equal(p.current, q.current)


def test_total_hours_is_the_sum_of_durations(lib: Library) -> None:
    assert lib.total_hours == pytest.approx(sum(p.duration for p in lib) / 3600)
    assert 300 < lib.total_hours < 500  # ours: 414.92 h; paper: 329.65 h with an undisclosed grid


def test_hdf5_round_trip_keeps_everything(lib: Library, tmp_path: Path) -> None:
    small = Library(list(lib)[::50], counts=lib.counts, meta=lib.meta)
    small.screen(lambda p: (p.max_abs_current < 10.0, None if p.max_abs_current < 10.0 else "too hot"))
    path = small.save(tmp_path / "lib.h5")
    back = Library.load(path)
    assert back.ids == small.ids
    assert back.counts == small.counts
    assert back.screening == small.screening
    assert back.meta["grid"]["pulse"]["width_s"] == list(lib.meta["grid"]["pulse"]["width_s"])
    for p in small:
        q = back[p.id]
        np.testing.assert_array_equal(p.t, q.t)
        np.testing.assert_array_equal(p.current, q.current)
        assert (q.kind, q.soc0, dict(q.params)) == (p.kind, p.soc0, json.loads(json.dumps(dict(p.params))))


def test_screen_flags_and_never_renumbers(lib: Library) -> None:
    copy = Library(list(lib), counts=lib.counts)
    results = copy.screen(lambda p: (p.kind != "drive", "drive too hot" if p.kind == "drive" else None))
    assert len(copy) == 738 and copy.ids == lib.ids
    assert [p.id for p in copy.flagged()] == list(range(721, 739))
    assert len(copy.usable()) == 720
    assert results[721].reason == "drive too hot" and results[1].ok


def test_screen_hook_runs_at_build_and_with_a_custom_map() -> None:
    calls: list[int] = []

    def mapper(fn, items):  # noqa: ANN001, ANN202 - stands in for executor.map
        for p in items:
            calls.append(int(p.id))
            yield fn(p)

    built = Library.build(screen=lambda p: (True, None), map_fn=mapper)
    assert calls == built.ids and all(s.ok for s in built.screening.values())


def test_bad_screen_results_and_ids_are_errors(lib: Library, tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"\(ok, reason\)"):
        Library(list(lib)[:2]).screen(lambda p: True)  # type: ignore[arg-type, return-value]
    with pytest.raises(InputError, match="no profile with id 739"):
        lib[739]
    with pytest.raises(InputError, match="integer"):
        lib["abc"]
    (tmp_path / "x.h5").write_bytes(b"not hdf5")
    with pytest.raises(InputError, match="not an HDF5 file"):
        Library.load(tmp_path / "x.h5")


def test_soc_window_rule_for_a_net_discharging_profile() -> None:
    p = Profile([0.0, 3600.0], [-0.5, -0.5])  # -0.5 Ah: stays inside [0, 1] from 0.2 ...
    assert p.soc(2.7, 0.2).min() > 0
    assert not soc_window_ok(p, 0.2)  # ... but the paper excludes net discharge from 20 %
    assert soc_window_ok(p, 0.4)


def test_select_by_generating_parameters(lib: Library) -> None:
    """Selections are compared with the paper's Table 10 by parameters, not ids."""
    hits = lib.select(kind="pulse", soc0=0.6, width_s=10.0, rest_factor=2, direction="charge")
    assert [p.params["total_s"] for p in hits] == [900.0, 1800.0, 3600.0]  # 600 s breaks 5C at n = 2
    assert lib.select(kind="drive", cycle="dc2", soc0=0.4)[0].id == 738
    with pytest.raises(InputError, match="unknown kind"):
        lib.select(kind="square")


def test_protocols_never_imports_battlab_or_drivers() -> None:
    import subprocess
    import sys

    code = (
        "import sys, pkgutil, importlib, protocols\n"
        "for m in pkgutil.walk_packages(protocols.__path__, 'protocols.'):\n"
        "    importlib.import_module(m.name)\n"
        "bad = sorted(n for n in sys.modules if n.split('.')[0] in ('battlab', 'drivers', 'pybamm'))\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
