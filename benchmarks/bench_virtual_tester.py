"""Benchmark the virtual tester: real-time factor over the loopback SCPI socket, and per-sample overhead.

1. Per-sample driver overhead: the wall time of one ``measure()`` (one compound SCPI query: V, I, T and the
   instrument's clock), of one ``set_current()`` (a setting confirmed by an inline ``SYST:ERR?``) and of the
   pair, over a real loopback socket to a virtual lab running in the same process (so the figure includes the
   server's work: advancing the cell to "now" and generating the physical noise).
2. One virtual hour of a pulse profile sampled every virtual second, served at several speeds: the host
   sleeps on the instrument's clock, sets the current when the profile changes and measures once per
   sample. Reported: wall time, achieved real-time factor (virtual s / wall s; target ≥ 1000×), and the
   sampling lateness in virtual s (how late each sample was against its schedule).

Physics: the drivers' stand-in equivalent-circuit cell (battlab's DFN is benchmarked by battlab).
Run: ``python benchmarks/bench_virtual_tester.py [--quick]``; prints a table and a JSON line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from collections.abc import Iterator

import numpy as np

from battlab.lab import virtual
from drivers.scpi.cycler import ScpiCycler
from drivers.virtual.lab import VirtualLab, VirtualLabConfig

TARGET_RTF = 1000.0


def _stats_us(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples) * 1e6
    return {
        "median_us": float(np.median(a)),
        "p99_us": float(np.percentile(a, 99)),
        "mean_us": float(a.mean()),
    }


def bench_overhead(n: int) -> dict[str, dict[str, float]]:
    with VirtualLab(config=VirtualLabConfig(speed=1000.0)) as lab:
        cyc = ScpiCycler.open(lab.cycler_url)
        cyc.set_current(0.5)
        cyc.output(True)
        for _ in range(200):  # warm-up
            cyc.measure()
        out: dict[str, dict[str, float]] = {}
        for name, op in (
            ("measure", cyc.measure),
            ("set_current", lambda: cyc.set_current(0.5)),
            ("set_current+measure", lambda: (cyc.set_current(0.5), cyc.measure())),
        ):
            samples = []
            for _ in range(n):
                t0 = time.perf_counter()
                op()
                samples.append(time.perf_counter() - t0)
            out[name] = _stats_us(samples)
        c = lab.cycler
        out["physics_step"] = {
            "mean_us": 1e6 * c.physics_wall_s / max(1, c.physics_steps),
            "steps": float(c.physics_steps),
            "load": lab.physics_load(),
        }
        cyc.output(False)
        cyc.close()
    return out


def pulse_profile(duration_s: int) -> np.ndarray:
    """Current / A at each virtual second: 1C (2.7 A) pulses of 60 s, charge and discharge, with rests."""
    pattern = [2.7] * 60 + [0.0] * 30 + [-2.7] * 60 + [0.0] * 30 + [1.35] * 120 + [-1.35] * 120
    reps = duration_s // len(pattern) + 1
    return np.tile(pattern, reps)[:duration_s]


@contextlib.contextmanager
def serve(speed: float, where: str) -> Iterator[str]:
    """The cycler's URL, served in this process (a thread) or by ``battlab virtual-tester serve``."""
    if where == "thread":
        with VirtualLab(
            config=VirtualLabConfig(speed=speed, soc0=0.5, modbus_port=None, modbus_rtu_port=None, espec_port=None)
        ) as lab:
            yield lab.cycler_url
        return
    with virtual.served("--speed", str(speed), "--physics", "standin", "--duration", "600") as urls:
        yield urls["cycler"]


def bench_virtual_hour(
    speed: float, where: str = "thread", duration_s: int = 3600, period_s: float = 1.0
) -> dict[str, float | str]:
    profile = pulse_profile(duration_s)
    with serve(speed, where) as url:
        cyc = ScpiCycler.open(url)
        cyc.set_voltage_limits(2.5, 4.2)
        cyc.set_current(0.0)
        cyc.output(True)
        clock = cyc.clock()
        lateness: list[float] = []
        current = 0.0
        t0_virtual = clock.now() + 2.0
        clock.sleep_until(t0_virtual)
        wall0 = time.perf_counter()
        for k in range(int(duration_s / period_s)):
            scheduled = t0_virtual + k * period_s
            clock.sleep_until(scheduled)
            if profile[k] != current:
                current = float(profile[k])
                cyc.set_current(current)
            m = cyc.measure()
            assert m.t_s is not None
            lateness.append(m.t_s - scheduled)
        wall = time.perf_counter() - wall0
        virtual = clock.now() - t0_virtual
        tripped = cyc.protection().tripped
        cyc.output(False)
        cyc.close()
    late = np.asarray(lateness)
    return {
        "server": where,
        "speed": speed,
        "samples": float(len(late)),
        "wall_s": wall,
        "virtual_s": virtual,
        "rtf": virtual / wall,
        "lateness_median_s": float(np.median(late)),
        "lateness_p99_s": float(np.percentile(late, 99)),
        "late_over_half_period": float(np.mean(late > 0.5 * period_s)),
        "tripped": float(tripped),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples and speeds")
    args = parser.parse_args()
    n = 500 if args.quick else 3000
    speeds = [1000.0, 2000.0] if args.quick else [1000.0, 2000.0, 5000.0]

    overhead = bench_overhead(n)
    print(f"per-sample driver overhead over loopback SCPI ({n} calls, stand-in physics)")
    for name, s in overhead.items():
        if name == "physics_step":
            continue
        print(f"  {name:<22} median {s['median_us']:7.1f} us   p99 {s['p99_us']:7.1f} us")
    ps = overhead["physics_step"]
    print(f"  stand-in physics: {ps['mean_us']:.1f} us per 1 s step ({ps['load']:.1%} of real time at 1000x)")
    max_rtf = 1.0 / (overhead["set_current+measure"]["median_us"] * 1e-6)
    print(
        f"  => at 1 sample per virtual second the link alone allows ~{max_rtf:,.0f}x real time "
        f"({max_rtf / TARGET_RTF:.1f}x the 1000x target)"
    )

    print("\none virtual hour, 1 s sampling, pulse profile (set_current on change + measure per sample)")
    print(
        f"  {'server':<8}{'speed':>7} {'wall s':>7} {'RTF':>7} {'RTF/1000':>8} {'late med s':>10} "
        f"{'late p99 s':>10} {'>0.5 s late':>11}"
    )
    hours = []
    for where in ("thread", "process"):
        for speed in speeds:
            r = bench_virtual_hour(speed, where)
            hours.append(r)
            print(
                f"  {where:<8}{speed:>7.0f} {r['wall_s']:>7.2f} {r['rtf']:>7.0f} "
                f"{r['rtf'] / TARGET_RTF:>8.2f} "
                f"{r['lateness_median_s']:>10.3f} {r['lateness_p99_s']:>10.3f} "
                f"{r['late_over_half_period']:>11.1%}"
            )
    print(json.dumps({"overhead": overhead, "virtual_hour": hours, "target_rtf": TARGET_RTF}))


if __name__ == "__main__":
    main()
