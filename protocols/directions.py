"""The direction of a library profile: charge only, discharge only, or both."""

from enum import Enum


class Direction(Enum):
    """Which way a pulse or sinusoid profile moves charge (positive current = charge)."""

    DISCHARGE = "discharge"
    CHARGE = "charge"
    BOTH = "both"

    @property
    def sign(self) -> int:
        """+1 for charge, -1 for discharge, 0 for charge-neutral (both)."""
        return {Direction.DISCHARGE: -1, Direction.CHARGE: 1, Direction.BOTH: 0}[self]
