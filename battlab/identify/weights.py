"""The fit's weights (eqs. 36–40): which noise model weighs the residuals, and where it came from.

In order: a noise model given (a :class:`battlab.noise.NoiseModel`, or a file ``noise.toml`` / the campaign's
``noise.json``, :func:`battlab.noise.load`); else eq. 38 fitted to the repeated trials found in the run logs
(:func:`battlab.identify.runlog.repeated_trials`: the noise trials a plan carries, or the trials of a plan run with
``repeat`` > 1; eq. 36 gives each profile's q); else the paper's coefficients, which belong to another tester. The
noise trials themselves are not fitted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from battlab.identify.experiments import Experiment, variance_of
from battlab.noise import NoiseModel, direction, intensity, load, repeat_noise

#: what the summary says when neither a model nor repeated trials were given
PAPER = "the paper's eq. 38 coefficients (no repeated trials in the data, no noise model given)"


def weigh(
    exps: Sequence[Experiment], noise: NoiseModel | str | Path | None = None
) -> tuple[list[Experiment], NoiseModel, dict[str, Any]]:
    """The experiments to fit (noise trials left out), each weighted by the chosen noise model; the model; and
    the summary's ``noise`` entry: ``{"source", "model": {a_c, b_c, a_d, b_d, floor}, "trials": [{"key",
    "profile", "direction", "intensity", "trials", "q_V"}]}``."""
    from battlab.identify import runlog

    found = runlog.repeated_trials(exps)
    rows = [
        {
            "key": key,
            "profile": str(prof.params.get("library_id", prof.id)),
            "direction": direction(prof).value,
            "intensity": intensity(prof),
            "trials": int(v.shape[0]),
            "q_V": repeat_noise(v),
        }
        for key, prof, v in found
    ]
    if isinstance(noise, NoiseModel):
        model, source = noise, "given"
    elif noise is not None:
        model, source = load(noise), f"file {noise}"
    elif found:
        model = NoiseModel.fit([(prof, v) for _, prof, v in found])
        n = sum(r["trials"] for r in rows)
        source = f"fitted to repeated trials ({len(rows)} profiles, {n} trials; eq. 36-38)"
    else:
        model, source = NoiseModel(), PAPER
    kept = [
        replace(e, variance=variance_of(e.scored_profile, model))
        for e in exps
        if not e.profile.params.get("noise_trial")
    ]
    return kept, model, {"source": source, "model": model.to_dict(), "trials": rows}
