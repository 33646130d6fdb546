"""The library sensitivity sweep, the design's first step: every profile simulated with all 18 sensitivities,
stored in HDF5.

Each library profile is simulated from its start SOC with the voltage and surface-temperature sensitivities
w.r.t. the normalised parameters θ̄ (eq. 1); the constraint screen (:mod:`battlab.design.screening`:
T_surface ≤ 50 °C, voltage window, stoichiometry) flags it, a simulation that fails is recorded with its reason.
The store holds one group per profile (``/profiles/0339``), written atomically (a temporary group renamed when
complete, then a flush) so a killed sweep resumes where it stopped. Every group carries a key: the SHA-256 of
the cell's parameters (``Cell.hash``), the profile (its t and current), the model version
(``battlab.__version__`` and :data:`MODEL_VERSION`), the model's source files and the sweep settings; a group
whose key differs is stale and recomputed, and a store made for another cell or model version is refused with
the reason.

The Fisher information (eqs. 22, 25) uses the voltage at 1 s sampling: the profile's own samples are all kept
(pulse edges at half seconds too), and the rows at whole seconds feed ``R``, the triangular factor of the
unweighted sensitivity matrix S (Sᵀ S = Rᵀ R), which is all that identifiability and design need.

Runs on local processes (``workers``) or on a Dask distributed cluster (``scheduler``).
"""

from battlab.design.sweep.keys import (
    CONVENTIONAL,
    FORMAT,
    FORMAT_VERSION,
    GROUP,
    MODEL_VERSION,
    TMP_PREFIX,
    SweepConfig,
    id_value,
    model_source_hash,
    model_version,
    profile_hash,
    result_key,
)
from battlab.design.sweep.run import Executor, SweepReport, dask_executor, local_executor, select_profiles, sweep
from battlab.design.sweep.store import SensitivityStore, group_name
from battlab.design.sweep.task import Outcome, Task, one_second_rows, resample_1s, run_task, triangular_factor

__all__ = [
    "CONVENTIONAL",
    "Executor",
    "FORMAT",
    "FORMAT_VERSION",
    "GROUP",
    "MODEL_VERSION",
    "Outcome",
    "SensitivityStore",
    "SweepConfig",
    "SweepReport",
    "TMP_PREFIX",
    "Task",
    "dask_executor",
    "group_name",
    "id_value",
    "local_executor",
    "model_source_hash",
    "model_version",
    "one_second_rows",
    "profile_hash",
    "resample_1s",
    "result_key",
    "run_task",
    "select_profiles",
    "sweep",
    "triangular_factor",
]
