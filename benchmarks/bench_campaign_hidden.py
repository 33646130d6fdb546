"""The campaign finds what its truth hides: ``battlab campaign --quick`` on virtual truths that carry one catalog
effect (or none), each as a user would run it, and what its diagnosis stage says.

Each case is a campaign TOML (``[campaign] truth = "nca18650-true+KEY:NAME=VALUE,..."``, ``seed``) run by the
installed command in its own directory; per case the table gives the cause expected (None: no hidden effect), the
cause kept, what the diagnosis named (``suggested``), the causes extended and scored, the mean validation RMSE
against the noise-free truth of the baseline (the better of the OED cell and its base refitted alone by the same
evaluations) and of the extended cell, the deciding experiments' lab hours and the campaign's wall time. A case is
right when the cause kept is the one hidden (null: none kept); the summary counts right, wrong (another cause kept)
and missed, and false alarms on the nulls.

    PYTHONPATH=$PWD python benchmarks/bench_campaign_hidden.py --out DIR [--cases a,b] [--jobs 2] [--json J]
    python benchmarks/bench_campaign_hidden.py --from-json J     # the table again, no runs

Sizes are the catalog's typical ones (:attr:`battlab.causes.cause.Cause.parameters`) or its example where a typical
size is not declared. Timing: about 6-10 minutes per case on 2 quiet cores; state ``uptime`` with the numbers. A case
whose directory holds a finished campaign is read, not run again (``--rerun`` runs it again: the campaign resumes
its finished stages, so delete the directory for a fresh run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

#: name → (truth, cause expected or None, seed)
CASES: dict[str, tuple[str, str | None, int]] = {
    "null_0": ("nca18650-true", None, 0),
    "null_1": ("nca18650-true", None, 1),
    "null_2": ("nca18650-true", None, 2),
    "hysteresis": ("nca18650-true+hysteresis:M_n=0.012,gamma_n=30", "hysteresis", 0),
    "contact_resistance": ("nca18650-true+contact_resistance:R_c=0.005", "contact_resistance", 0),
    "current_sensor": ("nca18650-true+current_sensor:offset=0.015,gain=0.005", "current_sensor", 0),
    "equilibrium": ("nca18650-true+equilibrium:d_sto_n=0.008,d_sto_p=0.008,dU=0.003", "equilibrium", 0),
    # fade during the campaign (a static loss before it is what its equilibrium stage measures)
    "capacity_fade": ("nca18650-true+capacity_fade:I_side=0.0015", "capacity_fade", 0),
    "electrolyte": ("nca18650-true+electrolyte:De_slope=0.4,kappa_slope=0.4,dlnf_slope=0.4", "electrolyte", 0),
    "solid_diffusion": ("nca18650-true+solid_diffusion:b_n=2.0,b_p=2.0", "solid_diffusion", 0),
    "thermal": ("nca18650-true+thermal:h2a_scale=1.5,dUdT_offset=0.0001", "thermal", 0),
}


def run_case(name: str, out: Path, rerun: bool) -> dict[str, Any]:
    """Run (or read) one case's campaign; its row."""
    truth, expected, seed = CASES[name]
    d = out / name
    summary = d / "summary.json"
    t0 = time.perf_counter()
    if rerun or not summary.exists():
        out.mkdir(parents=True, exist_ok=True)
        cfg = out / f"{name}.toml"
        cfg.write_text(f'[campaign]\ntruth = "{truth}"\nseed = {seed}\n')
        cmd = [sys.executable, "-c", "from battlab.cli import main; main()", "campaign", "--quick", "--quiet"]
        r = subprocess.run([*cmd, "--config", str(cfg), "-o", str(d)], capture_output=True, text=True)
        (out / f"{name}.log").write_text(r.stdout + r.stderr)
        if r.returncode != 0:
            lines = (r.stderr + r.stdout).strip().splitlines()
            return {"case": name, "expected": expected, "error": next((x for x in lines if x.startswith("error")), "")}
    s = json.loads(summary.read_text())
    dg = next(st["summary"] for st in s["stages"] if st["name"] == "diagnosis")
    g = dg.get("extension_gain") or {}
    return {
        "case": name,
        "truth": truth,
        "expected": expected,
        "kept": dg.get("cause"),
        "suggested": dg.get("suggested"),
        "extended": [t["cause"] for t in dg.get("extended", [])],
        "before_mV": g.get("rmse_before_mV"),
        "baseline": g.get("baseline"),
        "after_mV": g.get("rmse_after_mV"),
        "lab_hours_deciding": dg.get("lab_hours", 0.0),
        "wall_s": sum(st["wall_s"] for st in s["stages"]),
        "diagnosis_s": next(st["wall_s"] for st in s["stages"] if st["name"] == "diagnosis"),
        "validation_OED_mV": s.get("validation_rmse_mV"),
        "ran_s": time.perf_counter() - t0,
    }


def verdict(row: dict[str, Any]) -> str:
    if "error" in row:
        return "error"
    if row["kept"] == row["expected"]:
        return "right"
    if row["kept"] is None:
        return "missed"
    return "false alarm" if row["expected"] is None else "wrong"


def print_table(rows: list[dict[str, Any]]) -> None:
    def f(x: Any) -> str:
        return "–" if x is None else f"{x:.2f}"

    head = ["case", "expected", "kept", "diagnosis named", "extended", "baseline", "before mV", "after mV", "wall s"]
    head.append("verdict")
    body = [
        [
            r["case"],
            str(r["expected"]),
            str(r.get("kept")),
            str(r.get("suggested")),
            ",".join(r.get("extended", [])) or "–",
            str(r.get("baseline") or "–"),
            f(r.get("before_mV")),
            f(r.get("after_mV")),
            f"{r.get('wall_s', 0):.0f}",
            verdict(r) + (f" ({r['error']})" if "error" in r else ""),
        ]
        for r in rows
    ]
    widths = [max(len(x[i]) for x in [head, *body]) for i in range(len(head))]
    for line in [head, *body]:
        print("  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)))
    effects = [r for r in rows if r["expected"] is not None]
    nulls = [r for r in rows if r["expected"] is None]
    v = [verdict(r) for r in effects]
    print(
        f"\neffects: {v.count('right')} of {len(effects)} right, {v.count('wrong')} wrong, {v.count('missed')} missed; "
        f"nulls: {sum(verdict(r) == 'false alarm' for r in nulls)} false alarms in {len(nulls)}; "
        f"load {os.getloadavg()[0]:.1f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bench_campaign_hidden"))
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated case names")
    ap.add_argument("--jobs", type=int, default=2, help="campaigns run side by side")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--from-json", type=Path, default=None)
    ap.add_argument("--rerun", action="store_true")
    a = ap.parse_args()
    if a.from_json:
        print_table(json.loads(a.from_json.read_text()))
        return
    names = [n for n in a.cases.split(",") if n]
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise SystemExit(f"unknown cases {unknown}; expected some of {', '.join(CASES)}")
    print(f"{len(names)} campaigns, {a.jobs} at a time, load {os.getloadavg()[0]:.1f}", flush=True)
    with ThreadPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(lambda n: run_case(n, a.out, a.rerun), names))
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    print_table(rows)


if __name__ == "__main__":
    main()
