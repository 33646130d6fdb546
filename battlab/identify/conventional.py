"""The "conventional approach" baseline (paper, Validation): constant-current tests plus one drive cycle, all
parameters fitted at once with the same start point, optimiser and stopping rule as the OED fit.

Tests (positive current = charge, 1C = the cell's ``Q_nom``): discharges at C/10, C/5, C/3 and 2C from full
charge (SOC 1) to V_min, charges at C/5, C/2 and 1C from empty (SOC 0) to V_max, and the UDDS drive cycle from
SOC 0.8 (from SOC 1 its regenerative pulses would hit V_max at once)
(:func:`protocols.conventional` lists the same steps as a tester protocol; 0.5C and 1C discharges are left for
validation, Table 12). Constant-current tests are logged every ``dt_cc`` seconds (10 s), the drive cycle every
second. Each test is run until the cell's voltage limit (the logged data end there).
"""

from __future__ import annotations

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from battlab.identify.virtual import synthesize
from battlab.noise import NoiseModel
from protocols.drive_cycles import Cycle, drive_profile
from protocols.errors import InputError
from protocols.profile import Profile

DISCHARGE_C = (0.1, 0.2, 1 / 3, 2.0)
#: Start SOC of the discharges (full charge).
DISCHARGE_SOC0 = 1.0
CHARGE_C = (0.2, 0.5, 1.0)


def profiles(cell: Cell, *, dt_cc: float = 10.0) -> list[tuple[Profile, float]]:
    """(profile, start SOC) of the conventional tests; CC profiles are 1.3× their nominal duration long."""
    q = float(cell["Q_nom"])
    out: list[tuple[Profile, float]] = []
    for c in DISCHARGE_C:
        out.append(
            (Profile.constant(-c * q, 1.3 * 3600 / c, dt_cc, id=f"CC discharge {c:.3g}C", kind="cc"), DISCHARGE_SOC0)
        )
    for c in CHARGE_C:
        out.append((Profile.constant(c * q, 1.3 * 3600 / c, dt_cc, id=f"CC charge {c:.3g}C", kind="cc"), 0.0))
    out.append((drive_profile(Cycle.UDDS, soc0=0.8, id="UDDS"), 0.8))
    return out


def virtual_experiments(
    forward: ForwardModel, truth: Cell, *, seed: int, noise: NoiseModel | None = None, dt_cc: float = 10.0
) -> list[Experiment]:
    """The conventional tests on the virtual truth, cut where the true cell reaches its voltage limit."""
    exps = []
    th = forward.theta_of(truth)
    for k, (prof, soc0) in enumerate(profiles(truth, dt_cc=dt_cc)):
        out = forward.run(th, prof, soc0)
        n = out.voltage.size
        if n < 10 or (out.ended_by or "").startswith("solver"):
            raise InputError(f"conventional test {prof.id}: the true cell's simulation failed ({out.ended_by})")
        cut = Profile(
            prof.t[:n], np.r_[prof.current[: n - 1], prof.current[n - 2]], id=prof.id, kind=prof.kind, soc0=soc0
        )
        exps.append(
            synthesize(
                forward, truth, cut, soc0, seed=seed * 1000 + k, noise=noise, name=str(prof.id), clean=out.voltage
            )
        )
    return exps


def hours(experiments: list[Experiment]) -> float:
    """Total test time [h]."""
    return float(sum(e.hours for e in experiments))
