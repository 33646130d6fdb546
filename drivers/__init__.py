"""How to talk to instruments: transports, codecs, SCPI cyclers, chambers and the virtual tester.

Physics comes in through a small interface; ``drivers`` never imports ``battlab``.

Public surface::

    from drivers import Cycler, Chamber, Measurement, ProtectionState        # the interfaces
    from drivers import CyclerCapabilities, ChamberCapabilities              # what each instrument declares
    from drivers import open_cycler, open_chamber, open_instruments, parse_url
    from drivers import InstrumentError, CommunicationError, ReplyError, InstrumentFault, NotSupported
    from drivers.registry import register, UrlScheme                         # a driver registers its schemes
    from drivers.virtual.lab import VirtualLab, VirtualLabConfig             # the virtual tester
    from drivers.virtual.physics import CellPhysics, CellLimits              # what battlab implements
"""

from drivers.clock import Clock, RealClock, TrackedClock
from drivers.errors import CommunicationError, InstrumentError, InstrumentFault, NotSupported, ReplyError
from drivers.interfaces import (
    Chamber,
    ChamberCapabilities,
    Cycler,
    CyclerCapabilities,
    Instrument,
    InstrumentCapabilities,
    Measurement,
    ProtectionState,
)
from drivers.urls import InstrumentURL, parse_url

__all__ = [
    "Chamber",
    "ChamberCapabilities",
    "Clock",
    "CommunicationError",
    "Cycler",
    "CyclerCapabilities",
    "Instrument",
    "InstrumentCapabilities",
    "InstrumentError",
    "InstrumentFault",
    "InstrumentURL",
    "Measurement",
    "NotSupported",
    "ProtectionState",
    "RealClock",
    "ReplyError",
    "TrackedClock",
    "open_chamber",
    "open_cycler",
    "open_instruments",
    "parse_url",
]


def __getattr__(name: str):  # lazy: importing drivers does not import pymodbus
    if name in ("open_chamber", "open_cycler", "open_instruments"):
        from drivers import factory

        return getattr(factory, name)
    raise AttributeError(f"module 'drivers' has no attribute {name!r}")
