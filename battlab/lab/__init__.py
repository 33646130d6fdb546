"""The experiment runner: plans on a cycler and a chamber, safely, logged, catalogued and resumable.

Plans say what (:mod:`battlab.lab.plan`: a protocol plus run options); the run engine decides how
(:mod:`battlab.lab.engine`, an explicit state machine) and emits documents (:mod:`battlab.lab.documents`) to the
HDF5 log, the SQLite run catalog (:mod:`battlab.lab.catalog`) and the progress display. Step executors with
runner-side CV regulation: :mod:`battlab.lab.steps`; limits files and the safety envelope:
:mod:`battlab.lab.limits`, :mod:`battlab.lab.preflight`, :mod:`battlab.lab.safety`; the instruments and their links:
:mod:`battlab.lab.bench`; starting and resuming: :mod:`battlab.lab.session`.
"""

from battlab.lab.catalog import Catalog, RunRecord
from battlab.lab.engine import EngineConfig, RunEngine, RunState
from battlab.lab.limits import VIRTUAL_LIMITS, Envelope, InstrumentLimits
from battlab.lab.plan import Plan, PlanEntry, RunOptions
from battlab.lab.session import RunResult, RunSettings, resume_run, start_run

__all__ = [
    "Catalog",
    "EngineConfig",
    "Envelope",
    "InstrumentLimits",
    "Plan",
    "PlanEntry",
    "RunEngine",
    "RunOptions",
    "RunRecord",
    "RunResult",
    "RunSettings",
    "RunState",
    "VIRTUAL_LIMITS",
    "resume_run",
    "start_run",
]
