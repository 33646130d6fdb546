"""The lab's view of a plan: the shared plan schema of :mod:`battlab.io.plan` (protocol plus ``[run]``)."""

from battlab.io.plan import Plan, PlanEntry, RunOptions

__all__ = ["Plan", "PlanEntry", "RunOptions"]
