"""Replacements for designed profiles that cannot be run (battlab.design.replacement)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from battlab.design.information import Information
from battlab.design.replacement import Guard, replacements, run_designed


def _info() -> Information:
    """Six profiles informing parameter a, b or both: R_i = diag(√a_i, √b_i), q = 1."""
    strength = {1: (4.0, 0.0), 2: (0.0, 4.0), 3: (3.0, 0.0), 4: (0.0, 9.0), 5: (1.0, 0.1), 6: (0.5, 0.5)}
    R = np.array([np.diag(np.sqrt(s)) for s in strength.values()])
    return Information(tuple(strength), ("a", "b"), R, np.ones(len(strength)))


def test_a_lost_profile_is_replaced_by_the_candidate_that_restores_the_design_best() -> None:
    info = _info()
    design = SimpleNamespace(parameters=["a", "b"], selected=[1, 2])
    table = replacements(info, [design], "D")
    # without 1 the design knows nothing of a: 4 (b only) cannot replace it; 3 (a: 3) beats 5 and 6
    assert table[1][:3] == [3, 5, 6]
    assert 4 not in table[1]
    assert table[2][0] == 4  # and 2 is best replaced by the strongest b
    assert set(table) == {1, 2}


def test_aborted_profiles_are_replaced_and_those_predicted_to_abort_are_not_run() -> None:
    spans = {10: (2.9, 3.8), 20: (2.9, 3.9), 30: (3.5, 4.0), 11: (3.3, 3.9), 21: (3.4, 3.9), 22: (2.8, 3.9)}
    spares = {10: [22, 11], 20: [11, 21], 30: [11]}
    ran: list[int] = []

    def run(pid: int) -> tuple[bool, str, float]:
        ran.append(pid)
        if spans[pid][0] < 3.0:  # the cell met is 0.5 V lower than the design cell at these currents
            return False, "safety: voltage below 2.45 V", 2.44
        return True, "completed", float("nan")

    out = run_designed([10, 20, 30], spares, spans.__getitem__, run, Guard(2.45, 4.25))
    assert ran == [10, 11, 21, 30]  # 22 and 20 never run: no more margin than 10, which aborted
    assert [(a.designed, a.used) for a in out] == [(10, 11), (20, 21), (30, 30)]
    assert out[0].tried[10].startswith("safety") and out[0].tried[22].startswith("not run")
    assert out[1].tried[20].startswith("not run") and 11 not in out[1].tried  # 11 already fills slot 10


def test_a_slot_is_lost_when_every_spare_aborts_within_its_run_limit() -> None:
    spans = {1: (3.0, 4.0), 2: (3.0, 3.95), 3: (3.0, 3.9), 4: (3.0, 3.85)}  # each further below 4.25 V

    def run(pid: int) -> tuple[bool, str, float]:
        return False, "safety: voltage above 4.25 V", 4.26

    out = run_designed([1], {1: [2, 3, 4]}, spans.__getitem__, run, Guard(2.45, 4.25), max_runs=3)
    assert out[0].used is None
    assert list(out[0].tried) == [1, 2, 3]  # three runs, then the slot is lost
