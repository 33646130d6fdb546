"""The cell and library constants of the paper (Panasonic 18650 NCA, 2.7 Ah rated) used by the library.

Every function that depends on one of these takes it as a keyword argument; the values here are defaults.
"""

RATED_CAPACITY_AH = 2.7
"""Rated capacity [Ah]; the 1C current is this many amperes (docs/conventions.md: C = 2.7 A)."""

ONE_C_A = 2.7
"""The 1C current [A]."""

MAX_C_RATE = 5.0
"""Library constraint |I| <= 5C."""

MIN_DURATION_S = 600.0
"""Library constraint t_f >= 600 s."""

MAX_DURATION_S = 3600.0
"""Library constraint t_f <= 3600 s."""

L1_CHARGE_AH = 1.0
"""Every library profile is L1-normalised so that its charge throughput is exactly this [Ah]."""

START_SOCS = (0.8, 0.6, 0.4, 0.2)
"""Start SOCs of the library (paper Table 5), in library order."""

LOW_SOC = 0.2
"""No net-discharging profile starts from this SOC (paper's SOC-window rule)."""

HIGH_SOC = 0.8
"""No net-charging profile starts from this SOC (paper's SOC-window rule)."""

TABLE5_OCV = ((0.2, 3.4562), (0.4, 3.5982), (0.6, 3.7689), (0.8, 3.9481))
"""Paper Table 5: (SOC, equilibrium voltage [V]) of the paper's cell; a default for SOC set-points."""

SAMPLE_DT_S = 1.0
"""Library sampling interval [s] (finer only where a pulse edge needs it)."""
