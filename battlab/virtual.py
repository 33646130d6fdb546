"""Deprecated home of the virtual tester's cell; it lives in :mod:`battlab.lab.virtual`."""

import warnings

from battlab.lab.virtual import DFNPhysics, make_cell_physics, served  # noqa: F401

warnings.warn("battlab.virtual moved to battlab.lab.virtual", DeprecationWarning, stacklevel=2)
