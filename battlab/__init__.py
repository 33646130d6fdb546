"""battlab: optimally designed experiments and DFN parameter identification for lithium-ion cells."""

from battlab.cell import Cell
from battlab.io import bpx as _bpx  # noqa: F401  (registers the BPX cell format with Cell)
from battlab.simulation import Result, simulate
from protocols.errors import InputError

__version__ = "0.1.0"

__all__ = ["Cell", "InputError", "Result", "simulate", "__version__"]
