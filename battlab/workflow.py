"""The paper's steps as one function each, taking and returning values (see ``docs/workflow.md``):

- :func:`sweep` — every library profile with its 18 sensitivities into a store (eqs. 1, 22);
- :func:`groups` — ranking and parameter groups (Fig. 4, Table 9);
- :func:`design` — the optimal selection per group and the plan (eqs. 26–35, Table 10);
- :func:`fit` — equilibrium and dynamic identification with intervals (eqs. 10–21, 41–46);
- :func:`validate` — RMSE of cells on held-out data (Tables 12–14).

They print nothing; progress goes to subscribers (:mod:`battlab.progress`) or callbacks.
"""

from battlab.design.workflow import design, groups, sweep
from battlab.identify.validate import validate
from battlab.identify.workflow import fit

__all__ = ["design", "fit", "groups", "sweep", "validate"]
