"""The "conventional" test set of the paper as sensitivity-sweep profiles (for the design's efficiency baseline).

The same tests as :func:`protocols.standard.conventional` (its defaults): constant-current discharges at C/10,
C/5, C/3 and 2C from full, charges at C/5, C/2 and 1C from empty, and the UDDS drive cycle from SOC 0.8. Each
constant-current test runs until the voltage limit stops it and is followed by the protocol's hour of rest (the
sweep cuts it there: ``Task.extend_rest_s``); the drive cycle is the library's profile followed by the rest.
"""

from __future__ import annotations

import numpy as np

from protocols.constants import RATED_CAPACITY_AH
from protocols.drive_cycles import Cycle, drive_profile
from protocols.profile import Profile

DISCHARGE_C_RATES = (0.1, 0.2, 1 / 3, 2.0)
CHARGE_C_RATES = (0.2, 0.5, 1.0)
REST_S = 3600.0
"""Rest after each test [s] (as in :func:`protocols.standard.conventional`)."""


def _cc(c_rate: float, capacity_ah: float, soc0: float, name: str) -> Profile:
    """Constant current at ``c_rate`` (positive = charge) for 1.3 h / |c_rate|, 1 s samples."""
    duration = float(np.ceil(1.3 * 3600.0 / abs(c_rate)))
    t = np.arange(duration + 1.0)
    return Profile(
        t,
        np.full(t.size, c_rate * capacity_ah),
        id=name,
        kind="conventional",
        soc0=soc0,
        params={"name": name, "c_rate": c_rate},
    )


def conventional_profiles(capacity_ah: float = RATED_CAPACITY_AH) -> list[Profile]:
    """The conventional tests, each to be run to its limit and followed by :data:`REST_S` of rest."""
    out = [_cc(-c, capacity_ah, 1.0, f"cc_discharge_{c:.3g}C") for c in DISCHARGE_C_RATES]
    out += [_cc(c, capacity_ah, 0.0, f"cc_charge_{c:.3g}C") for c in CHARGE_C_RATES]
    udds = drive_profile(Cycle.UDDS, soc0=0.8)
    out.append(udds.with_meta(id="drive_udds", kind="conventional", params={"name": "UDDS from SOC 0.8"}))
    return out
