"""The paper's steps and battlab's own workflows as one function each, taking one options value (or values) and
returning a report (see ``docs/workflow.md``):

- :func:`sweep` — every library profile with its 18 sensitivities into a store (eqs. 1, 22);
- :func:`groups` — ranking and parameter groups (Fig. 4, Table 9);
- :func:`design` — the optimal selection per group and the plan (eqs. 26–35, Table 10);
- :func:`fit` — equilibrium and dynamic identification with intervals (eqs. 10–21, 41–46) from a :class:`FitOptions`;
- :func:`validate` — RMSE of cells on held-out data (Tables 12–14);
- :func:`diagnose` — what the model gets wrong on logged data, and which cause explains it;
- :func:`campaign` — the whole loop on a bench (or the virtual tester), resumable.

They print nothing; progress goes to subscribers (:mod:`battlab.progress`): the command line subscribes its
display, a notebook its own.
"""

from battlab.campaign.run import run_campaign as campaign
from battlab.design.workflow import design, groups, sweep
from battlab.diagnose.workflow import diagnose
from battlab.identify.fit_options import FitOptions
from battlab.identify.fit_report import on_equilibrium, on_stage
from battlab.identify.validate import validate
from battlab.identify.workflow import fit

__all__ = [
    "FitOptions",
    "campaign",
    "design",
    "diagnose",
    "fit",
    "groups",
    "on_equilibrium",
    "on_stage",
    "sweep",
    "validate",
]
