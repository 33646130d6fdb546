"""One fit's held-out check in a diagnosis (:mod:`battlab.diagnose.confirm` makes them, the report shows them)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Confirmation:
    """One fit's held-out check: the fitted parameters and the RMSE [mV] (and [K]) on the held-out part."""

    cause: str
    names: tuple[str, ...]
    values: dict[str, float]
    rmse_train_mV: float
    rmse_held_out_mV: float
    converged: bool
    held_out_metric: float = float("nan")  # RMS of the held-out errors over each channel's noise (1: the noise)
    rmse_held_out_K: float | None = None  # the surface temperature's, where logged
