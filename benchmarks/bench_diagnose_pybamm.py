"""``battlab diagnose`` measured on data made by PyBaMM (benchmarks/pybamm_effects.py): does it name the hidden cause,
name nothing on PyBaMM's plain DFN, and predict held-out data better when it names one?

Run ``python benchmarks/pybamm_effects.py --data DIR`` first (the cached cases), then
``python benchmarks/bench_diagnose_pybamm.py --data DIR [--cases a,b] [--json out.json]``: ``battlab diagnose`` runs
through its command line in a subprocess (this checkout first on the path) on every cached case, with the cell file
made for it, and the script prints

- per case: the expected catalog key, the cause named, the outcome, the held-out RMSE of the baseline (the better of
  the unrefitted cell and the base refit; the cell alone for a cause named as a refit of its own base parameters)
  and of the named cause's fit with the gain, the effect's size (PyBaMM's
  noise-free RMSE against its plain DFN on the same profile: how far the effect is from a null at all), the
  diagnosis's wall time, and the summary's ``cannot_tell`` pairs;
- the confusion table (expected key × named cause; ``null`` for the plain DFN, ``-`` for nothing named);
- the counts the targets need, each with met or MISSED: effect cases named right (>= 90 %), named wrongly (<= 1 in
  all), nulls named (<= 10 %), held-out gain wherever a cause is named (>= 30 %), a diagnosis of 4 h at 1 s
  (<= 3 min).

``--json FILE`` writes every summary with the case's record, so the tables can be recomputed (``--from-json FILE``
prints them again without running anything). ``--reuse`` keeps reports already in the output folder (resuming an
interrupted run). The load of the machine (``uptime``) is printed before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import pybamm_effects as pe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: the targets: share of effect cases named right, wrong causes in all, share of nulls named, held-out gain wherever
#: a cause is named, seconds per diagnosis of 4 h at 1 s
TARGET_RIGHT = 0.9
TARGET_WRONG = 1
TARGET_NULLS = 0.1
TARGET_GAIN = 0.3
TARGET_SECONDS = 180.0


def diagnose_cli(csv: Path, cell: Path, outdir: Path, timeout: float = 3600.0) -> tuple[dict[str, Any], float]:
    """``battlab diagnose CSV --cell CELL -o OUTDIR`` in a subprocess with this checkout first on the path: its
    summary.json and the wall time [s]; a failed run raises with the end of its stderr."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
    }
    cli = "from battlab.cli import main; main()"
    cmd = [sys.executable, "-c", cli, "diagnose", str(csv), "--cell", str(cell), "-o", str(outdir)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, check=False, cwd=ROOT)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"battlab diagnose exit {proc.returncode}: {proc.stderr.strip()[-600:]}")
    return json.loads((outdir / "summary.json").read_text()), wall


def effect_size(case: pe.Case, data: Path) -> dict[str, float] | None:
    """PyBaMM's noise-free voltage [mV] and temperature [K] RMSE of ``case`` against the plain DFN on its profile
    (None without that null in ``data``); for a current sensor, the charge [mAh] its log misstates at the end."""
    null = next((c for c in pe.CASES.values() if c.cause is None and c.profile == case.profile), None)
    if case.cause is None or null is None or pe.cached(null, data) is None:
        return None
    a = np.load(pe.paths(data, case.name)["truth"])
    b = np.load(pe.paths(data, null.name)["truth"])
    out = {
        "V_mV": 1e3 * float(np.sqrt(np.mean((a["voltage"] - b["voltage"]) ** 2))),
        "T_K": float(np.sqrt(np.mean((a["temperature"] - b["temperature"]) ** 2))),
    }
    gain, offset = case.sensor
    if gain or offset:
        i, t = a["current"], a["t"]
        out["charge_mAh"] = 1e3 * float(np.sum((gain * i[:-1] + offset) * np.diff(t))) / 3600.0
    return out


def held_out(summary: dict[str, Any]) -> tuple[float | None, float | None, float | None]:
    """(baseline, after, gain): the held-out RMSE [mV] of the better of the unrefitted cell and the base refit, of
    the fit of the cause named, and the gain 1 − after/baseline (None where nothing was fitted or named). A cause
    named as a refit of its own base parameters (``"how": "refit"``: the cause-blind base refit found the same
    explanation) is measured against the unrefitted cell: the base refit is then that cause's fix, not a rival."""
    g = summary.get("extension_gain") or {}
    keys = (
        ("rmse_cell_mV",) if summary.get("how") == "refit" else ("rmse_before_mV", "rmse_cell_mV", "rmse_base_refit_mV")
    )
    base = [g.get(k) for k in keys]
    base = [x for x in base if isinstance(x, int | float)]
    baseline = min(base) if base else None
    after = g.get("rmse_after_mV")
    gain = 1.0 - after / baseline if baseline and after is not None and summary.get("cause") else None
    return baseline, after, gain


def pairs(summary: dict[str, Any]) -> list[str]:
    """The summary's ``cannot_tell`` entries as text: the causes and the experiment that separates them."""
    out = []
    for c in summary.get("cannot_tell") or []:
        causes = c.get("causes") or [c.get("cause")]
        exp = c.get("experiment") or c.get("reason") or ""
        out.append("/".join(str(x) for x in causes) + (f" ({exp})" if exp else ""))
    return out


def outcome(expected: str | None, named: str | None) -> str:
    """``right``, ``wrong`` or ``not named`` for an effect case; ``quiet`` or ``FALSE ALARM`` for a null."""
    if expected is None:
        return "quiet" if named is None else "FALSE ALARM"
    if named is None:
        return "not named"
    return "right" if named == expected else "wrong"


def run(names: list[str], data: Path, out: Path, reuse: bool, timeout: float) -> list[dict[str, Any]]:
    """Diagnose every cached case of ``names``; one row per case (``error`` for a case missing or failed)."""
    rows = []
    for name in names:
        case = pe.CASES[name]
        row: dict[str, Any] = {"name": name, "expected": case.cause, "size": case.size}
        record = pe.cached(case, data)
        if record is None:
            rows.append({**row, "error": "not in the cache (python benchmarks/pybamm_effects.py --data DIR)"})
            print(f"{name:<22} not cached", flush=True)
            continue
        p = pe.paths(data, name)
        report = out / name
        row.update(record=record, effect=effect_size(case, data))
        try:
            if reuse and (report / "summary.json").is_file():
                summary, wall = json.loads((report / "summary.json").read_text()), float("nan")
            else:
                summary, wall = diagnose_cli(p["csv"], p["cell"], report, timeout)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            rows.append({**row, "error": str(exc)})
            print(f"{name:<22} FAILED {exc}", flush=True)
            continue
        row.update(summary=summary, seconds=wall)
        rows.append(row)
        print(line(row), flush=True)
    return rows


def _f(x: float | None, spec: str = ".2f") -> str:
    return "-" if x is None or (isinstance(x, float) and np.isnan(x)) else format(x, spec)


def line(row: dict[str, Any]) -> str:
    """One case as a line of the per-case table."""
    if "error" in row:
        return f"{row['name']:<22} {row['expected']!s:<18} ERROR {row['error'][:200]}"
    s = row["summary"]
    base, after, gain = held_out(s)
    eff = row.get("effect") or {}
    size = _f(eff.get("V_mV")) + (f"/{eff['T_K']:.2f}K" if eff.get("T_K", 0.0) > 0.05 else "")
    if "charge_mAh" in eff:
        size = f"{eff['charge_mAh']:.0f}mAh"
    secs = s.get("seconds", row.get("seconds"))
    return (
        f"{row['name']:<22} {row['expected']!s:<18} {s.get('cause')!s:<18} "
        f"{outcome(row['expected'], s.get('cause')):<11} "
        f"{_f(base):>7} {_f(after):>7} {_f(None if gain is None else 100 * gain, '.0f'):>5} {size:>12} "
        f"{_f(secs, '.0f'):>5}  {'; '.join(pairs(s))}"
    )


HEADER = (
    f"{'case':<22} {'expected':<18} {'named':<18} {'outcome':<11} {'base mV':>7} {'after':>7} {'gain%':>5} "
    f"{'effect mV':>12} {'s':>5}  cannot tell"
)


def confusion(rows: list[dict[str, Any]]) -> str:
    """Expected key (rows; ``null`` for the plain DFN) × named cause (columns; ``-`` for nothing named)."""
    done = [r for r in rows if "summary" in r]
    count = Counter((r["expected"] or "null", r["summary"].get("cause") or "-") for r in done)
    truths = sorted({t for t, _ in count}, key=lambda t: (t == "null", t))
    named = sorted({n for _, n in count}, key=lambda n: (n == "-", n))
    width = max([len(n) for n in named] + [4])
    head = f"{'expected / named':<20}" + "".join(f"{n:>{width + 1}}" for n in named)
    lines = [head] + [
        f"{t:<20}" + "".join(f"{count.get((t, n), 0) or '.':>{width + 1}}" for n in named) for t in truths
    ]
    return "\n".join(lines)


def targets(rows: list[dict[str, Any]]) -> tuple[str, dict[str, Any]]:
    """The counts the targets need, as text and as numbers."""
    done = [r for r in rows if "summary" in r]
    effects = [r for r in done if r["expected"] is not None]
    nulls = [r for r in done if r["expected"] is None]
    oc = Counter(outcome(r["expected"], r["summary"].get("cause")) for r in done)
    gains = [(r["name"], held_out(r["summary"])[2]) for r in done if r["summary"].get("cause")]
    low = [(n, g) for n, g in gains if g is None or g < TARGET_GAIN]
    secs = [r["summary"].get("seconds", r.get("seconds")) for r in done]
    secs = [s for s in secs if isinstance(s, int | float) and not np.isnan(s)]
    n_eff, n_null = len(effects), len(nulls)
    wrong = oc["wrong"] + oc["FALSE ALARM"]
    nums = {
        "effect_cases": n_eff,
        "right": oc["right"],
        "wrong": oc["wrong"],
        "not_named": oc["not named"],
        "nulls": n_null,
        "nulls_named": oc["FALSE ALARM"],
        "named_below_gain": [n for n, _ in low],
        "seconds_max": max(secs) if secs else None,
        "seconds_median": statistics.median(secs) if secs else None,
        "failed": [r["name"] for r in rows if "error" in r],
    }

    def ok(good: bool) -> str:
        return "met" if good else "MISSED"

    share = oc["right"] / n_eff if n_eff else 0.0
    null_share = oc["FALSE ALARM"] / n_null if n_null else 0.0
    text = [
        f"effect cases named right: {oc['right']}/{n_eff} ({100 * share:.0f} %; target >= {100 * TARGET_RIGHT:.0f} %: "
        f"{ok(share >= TARGET_RIGHT)}); named wrongly {oc['wrong']}, not named {oc['not named']}",
        f"nulls named: {oc['FALSE ALARM']}/{n_null} ({100 * null_share:.0f} %; target <= {100 * TARGET_NULLS:.0f} %: "
        f"{ok(null_share <= TARGET_NULLS)})",
        f"wrong causes in all (effects named wrongly + nulls named): {wrong} (target <= {TARGET_WRONG}: "
        f"{ok(wrong <= TARGET_WRONG)})",
        f"held-out gain wherever named: {len(gains) - len(low)}/{len(gains)} at >= {100 * TARGET_GAIN:.0f} % "
        f"({ok(not low)})"
        + (
            ": below in " + ", ".join(f"{n} {_f(None if g is None else 100 * g, '.0f')} %" for n, g in low)
            if low
            else ""
        ),
        f"diagnosis time: median {_f(nums['seconds_median'], '.0f')} s, max {_f(nums['seconds_max'], '.0f')} s "
        f"(target <= {TARGET_SECONDS:.0f} s per 4 h: {ok(bool(secs) and max(secs) <= TARGET_SECONDS)})",
    ]
    if nums["failed"]:
        text.append(f"not diagnosed (missing or failed): {', '.join(nums['failed'])}")
    return "\n".join(text), nums


def report(rows: list[dict[str, Any]]) -> str:
    """Every table of the benchmark as text."""
    text, _ = targets(rows)
    return "\n\n".join(
        [HEADER + "\n" + "\n".join(line(r) for r in rows), "confusion (expected x named):\n" + confusion(rows), text]
    )


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        return "uptime unavailable"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="the case cache of benchmarks/pybamm_effects.py")
    ap.add_argument("--cases", default=None, help="comma-separated case names (default: every case)")
    ap.add_argument("--out", default=None, help="the diagnosis reports' folder (default DATA/reports)")
    ap.add_argument("--json", default=None, help="write every case's summary and record here")
    ap.add_argument("--from-json", default=None, help="print the tables of a saved --json file; run nothing")
    ap.add_argument("--reuse", action="store_true", help="keep the reports already in --out (resume a run)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per diagnosis before it counts as failed")
    ap.add_argument("--nice", type=int, default=10, help="lower the priority by this (default 10)")
    args = ap.parse_args(argv)
    if args.from_json:
        print(report(json.loads(Path(args.from_json).read_text())["cases"]))
        return 0
    if not args.data:
        ap.error("--data DIR is needed (or --from-json FILE)")
    names = args.cases.split(",") if args.cases else list(pe.CASES)
    unknown = [n for n in names if n not in pe.CASES]
    if unknown:
        ap.error(f"unknown case(s) {unknown}; expected some of {', '.join(pe.CASES)}")
    if args.nice:
        os.nice(args.nice)
    data = Path(args.data)
    out = Path(args.out) if args.out else data / "reports"
    load_before = uptime()
    print(f"load before: {load_before}\n{HEADER}", flush=True)
    rows = run(names, data, out, args.reuse, args.timeout)
    load_after = uptime()
    print("\n" + report(rows) + f"\n\nload after: {load_after}", flush=True)
    if args.json:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT, check=False)
        dirty = subprocess.run(["git", "status", "--porcelain", "battlab"], capture_output=True, text=True, cwd=ROOT)
        doc = {
            "commit": head.stdout.strip(),
            "battlab_modified": bool(dirty.stdout.strip()),
            "load": [load_before, load_after],
            "targets": targets(rows)[1],
            "cases": rows,
        }
        Path(args.json).write_text(json.dumps(doc, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
