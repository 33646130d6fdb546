"""Current sensor error: the logged current is not the current the cell carries (an offset and a gain error of the
cycler's current measurement). A measurement model, not a change of the cell's physics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca

from battlab.causes.cause import Cause, Evidence
from battlab.causes.extension import Extension
from battlab.specs import extension_parameter

KEY = "current_sensor"
_SENSOR = "measurement model: a linear current sensor with offset and gain error (e.g. Arbin/Maccor specifications)"


@dataclass(frozen=True)
class CurrentSensor(Extension):
    """The logged current is a sensor's: I_log = (1 + gain) I_cell + offset (public sign, + = charge). The cell
    carries I_cell = (I_log − offset)/(1 + gain); the model's input stays the logged current."""

    key: ClassVar[str] = KEY

    def cell_current(self, c: Any, I_dis: ca.SX) -> ca.SX:
        # model sign (+ = discharge): I_dis,log = (1 + gain) I_dis,cell − offset
        return (I_dis + self.p(c, "offset")) / (1.0 + self.p(c, "gain"))


CAUSE = Cause(
    key=KEY,
    title="current sensor",
    mechanism="offset and gain error of the logged current",
    informed_by=Evidence(
        "pulse",
        "pulses in both directions with long rests (an offset drains the cell at rest, a gain scales charge and "
        "discharge alike)",
    ),
    extension=CurrentSensor,
    parameters=(
        extension_parameter(
            KEY, "offset", "A", (-0.05, 0.05), 0.0, "offset of the logged current (+ = charge)", _SENSOR, typical=0.015
        ),
        extension_parameter(
            KEY, "gain", "1", (-0.02, 0.02), 0.0, "relative gain error of the logged current", _SENSOR, typical=0.005
        ),
    ),
    slots=frozenset({"current_measurement"}),
    example={"offset": 0.02, "gain": 0.01},
    validated_by="exact: the cell's current is computed from the logged one (tests/battlab/model)",
    slow_cycle=("offset",),
)
