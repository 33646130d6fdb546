"""What current to apply: profiles, protocols, the OED input library, drive cycles, schedule exporters.

Depends on numpy and file-format libraries only; never on ``drivers`` or ``battlab``.
"""

from protocols.concatenate import Concatenation, ConcatenationReport, SocMethod, concatenate
from protocols.directions import Direction
from protocols.drive_cycles import Cycle, drive_profile, speed_trace
from protocols.errors import InputError
from protocols.ev_model import EVModel
from protocols.export import ExportResult, Format, export, read_back
from protocols.library import FilterCount, Library, ScreenResult
from protocols.profile import Profile
from protocols.protocol import (
    CCCV,
    Comparison,
    ConstantCurrent,
    ConstantVoltage,
    EndCondition,
    ProfileStep,
    Protocol,
    Quantity,
    Rest,
    SafetyLimits,
    StepKind,
)
from protocols.pulses import PulseSpec, pulse_profile
from protocols.sines import SineSpec, sine_profile
from protocols.standard import conventional, hppc, ocv_test

__all__ = [
    "CCCV",
    "Comparison",
    "Concatenation",
    "ConcatenationReport",
    "ConstantCurrent",
    "ConstantVoltage",
    "Cycle",
    "Direction",
    "EVModel",
    "EndCondition",
    "ExportResult",
    "FilterCount",
    "Format",
    "InputError",
    "Library",
    "Profile",
    "ProfileStep",
    "Protocol",
    "PulseSpec",
    "Quantity",
    "Rest",
    "SafetyLimits",
    "ScreenResult",
    "SineSpec",
    "SocMethod",
    "StepKind",
    "concatenate",
    "conventional",
    "drive_profile",
    "export",
    "hppc",
    "ocv_test",
    "pulse_profile",
    "read_back",
    "sine_profile",
    "speed_trace",
]
