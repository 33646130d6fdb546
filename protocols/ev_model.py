"""A longitudinal electric-vehicle model: vehicle speed -> cell current (positive = charge).

Road-load power at the wheels for the hold interval k (speed samples v_k, v_{k+1} at t_k, t_{k+1}; the
current computed for the interval is applied from t_k to t_{k+1}, matching the profiles' zero-order hold)::

    v = (v_k + v_{k+1}) / 2,  a = (v_{k+1} - v_k) / dt
    P_wheel = (k_r m a + m g (C_rr cos(theta) + sin(theta)) + rho C_d A v^2 / 2) v

The battery delivers P_wheel / eta_drive when P_wheel >= 0 (traction). When braking (P_wheel < 0) it takes
back eta_regen |P_wheel|, limited to ``regen_power_limit_w`` and only above ``regen_min_speed_mps`` (friction
brakes do the rest). An auxiliary load ``aux_power_w`` is always on. The pack's N = series x parallel
identical cells share the power equally at the nominal cell voltage, so the cell current is

    I_cell = -(P_battery) / (N V_cell)        (traction is negative current: discharge)

Default values describe a large 18650-NCA sedan, approximately a 2012 Tesla Model S 85 (public figures:
kerb mass ~2100 kg with driver, C_d = 0.24, A = 2.34 m^2, 96 s x 74 p = 7104 cells of ~3.2 Ah); they are
representative, not a calibrated vehicle. The library L1-normalises every drive profile to 1 Ah, which
removes the overall scale (pack size, cell voltage); the vehicle parameters still set the *shape*: the
ratio of aerodynamic to inertial load, how much braking energy comes back, and the auxiliary base load.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from protocols.errors import InputError

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class EVModel:
    """Vehicle and pack parameters (SI units)."""

    mass_kg: float = 2100.0
    rotating_mass_factor: float = 1.05
    drag_coefficient: float = 0.24
    frontal_area_m2: float = 2.34
    rolling_resistance: float = 0.009
    air_density_kg_m3: float = 1.2
    drivetrain_efficiency: float = 0.90
    regen_efficiency: float = 0.90
    regen_power_limit_w: float = 60e3
    regen_min_speed_mps: float = 2.0
    aux_power_w: float = 600.0
    cells_in_series: int = 96
    cells_in_parallel: int = 74
    cell_voltage_v: float = 3.6

    def __post_init__(self) -> None:
        positive = ("mass_kg", "frontal_area_m2", "air_density_kg_m3", "cell_voltage_v")
        for name in positive:
            if not getattr(self, name) > 0:
                raise InputError(f"EV model: {name} must be positive, got {getattr(self, name)}")
        for name in ("drivetrain_efficiency", "regen_efficiency"):
            if not 0 < getattr(self, name) <= 1:
                raise InputError(f"EV model: {name} must be in (0, 1], got {getattr(self, name)}")
        if self.cells_in_series < 1 or self.cells_in_parallel < 1:
            raise InputError("EV model: cells_in_series and cells_in_parallel must be at least 1")

    @property
    def n_cells(self) -> int:
        """Number of cells in the pack."""
        return self.cells_in_series * self.cells_in_parallel

    def as_dict(self) -> dict[str, float]:
        """The parameters as plain values (stored with each drive profile)."""
        return asdict(self)

    def wheel_power(self, t: np.ndarray, speed_mps: np.ndarray, grade: np.ndarray | None = None) -> np.ndarray:
        """Road-load power at the wheels [W] on each hold interval (length ``t.size - 1``)."""
        t = np.asarray(t, dtype=float)
        v = np.asarray(speed_mps, dtype=float)
        if t.size != v.size or t.size < 2:
            raise InputError(f"speed trace needs matching time and speed arrays (got {t.size}, {v.size})")
        dt = np.diff(t)
        if np.any(dt <= 0):
            raise InputError("speed trace: time must increase strictly")
        if np.any(v < 0):
            raise InputError("speed trace: negative speed")
        theta = np.zeros(dt.size) if grade is None else np.arctan(0.5 * (grade[:-1] + grade[1:]))
        v_mid = 0.5 * (v[:-1] + v[1:])
        acc = np.diff(v) / dt
        force = (
            self.rotating_mass_factor * self.mass_kg * acc
            + self.mass_kg * GRAVITY_M_S2 * (self.rolling_resistance * np.cos(theta) + np.sin(theta)) * (v_mid > 0)
            + 0.5 * self.air_density_kg_m3 * self.drag_coefficient * self.frontal_area_m2 * v_mid**2
        )
        return force * v_mid

    def battery_power(self, wheel_power_w: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """Pack power [W], positive when the pack delivers power (traction, auxiliaries)."""
        p = np.asarray(wheel_power_w, dtype=float)
        v = np.asarray(speed_mps, dtype=float)
        v_mid = 0.5 * (v[:-1] + v[1:]) if v.size == p.size + 1 else v
        traction = np.where(p > 0, p / self.drivetrain_efficiency, 0.0)
        regen = np.where(p < 0, np.maximum(p * self.regen_efficiency, -self.regen_power_limit_w), 0.0)
        regen = np.where(v_mid >= self.regen_min_speed_mps, regen, 0.0)
        return traction + regen + self.aux_power_w

    def cell_current(self, t: np.ndarray, speed_mps: np.ndarray, grade: np.ndarray | None = None) -> np.ndarray:
        """Cell current [A] on each hold interval, positive = charge (so traction is negative)."""
        p_batt = self.battery_power(self.wheel_power(t, speed_mps, grade), speed_mps)
        return -p_batt / (self.n_cells * self.cell_voltage_v)
