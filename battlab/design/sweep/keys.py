"""What identifies a sweep result: the model version and source hash, profile hashes, the sweep settings and
the per-profile key (a stale key means the result must be recomputed)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import battlab
from battlab import parameters
from battlab.design.screening import Limits
from battlab.model.mesh import Mesh
from protocols.profile import Profile

MODEL_VERSION = "dfn-thermal-1"
"""Version of the model's equations and numerics as far as stored sensitivities are concerned: bump it when a
change of the model makes old stores wrong (the source hash catches every change, this one says it matters)."""

FORMAT = "battlab-sensitivity"
FORMAT_VERSION = 1
GROUP = "profiles"
CONVENTIONAL = "conventional"
TMP_PREFIX = "_partial_"


def model_version() -> str:
    """``battlab <version> / <MODEL_VERSION>``: stores with another value are refused."""
    return f"battlab {battlab.__version__} / {MODEL_VERSION}"


def model_source_hash() -> str:
    """SHA-256 of the model's source (``battlab/model``, ``simulation.py``, ``parameters.py``)."""
    root = Path(battlab.__file__).parent
    files = sorted((root / "model").glob("*.py")) + sorted((root / "model").glob("*.c"))
    files += [root / "simulation.py", root / "parameters.py"]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def profile_hash(profile: Profile) -> str:
    """SHA-256 of a profile's samples (t [s], current [A], as float64) and its start SOC."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(profile.t, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(profile.current, dtype="<f8").tobytes())
    h.update(repr(None if profile.soc0 is None else float(profile.soc0)).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class SweepConfig:
    """What is computed: parameters (θ̄ names), ambient [K], thermal option, mesh, screen limits."""

    names: tuple[str, ...] = parameters.NAMES
    ambient: float = 298.15
    isothermal: bool = False
    mesh: Mesh = field(default_factory=Mesh)
    limits: Limits = field(default_factory=Limits)

    def to_json(self) -> str:
        return json.dumps(
            {
                "names": list(self.names),
                "ambient": self.ambient,
                "isothermal": self.isothermal,
                "mesh": asdict(self.mesh),
                "limits": asdict(self.limits),
            },
            sort_keys=True,
        )

    @classmethod
    def from_json(cls, text: str) -> SweepConfig:
        d = json.loads(text)
        return cls(tuple(d["names"]), d["ambient"], d["isothermal"], Mesh(**d["mesh"]), Limits(**d["limits"]))


def result_key(
    cell_hash: str, prof_hash: str, config: SweepConfig, source_hash: str, extend_rest_s: float = 0.0
) -> str:
    """The key of one stored result: any change of cell, profile, model or settings changes it."""
    parts = [cell_hash, prof_hash, model_version(), source_hash, config.to_json(), repr(float(extend_rest_s))]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def id_value(pid: Any) -> int | str:
    """Library ids are integers; conventional tests are named."""
    return int(pid) if isinstance(pid, int | np.integer) or str(pid).isdigit() else str(pid)
