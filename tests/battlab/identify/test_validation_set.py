"""The held-out validation set shared by bench_fit and bench_loop."""

from __future__ import annotations

import pytest

import battlab
from battlab.identify.forward import ForwardModel
from battlab.identify.validation import validation_profiles
from protocols.library import Library


@pytest.fixture(scope="module")
def setup():
    fm = ForwardModel(battlab.Cell.load("nca18650"))
    return fm, battlab.Cell.load("nca18650-true"), Library.build()


def test_seven_profiles_each_run_by_the_truth_to_its_end(setup) -> None:
    fm, truth, lib = setup
    val = validation_profiles(fm, truth, lib)
    assert [p.kind for p, _ in val] == ["cc", "cc", "sine", "pulse", "drive", "drive", "drive"]
    assert [s for p, s in val[4:]] == [0.6, 0.6, 0.6]
    for p, s in val:  # cut where the truth stops: the true cell covers every profile
        assert fm.run(fm.theta_of(truth), p, s).voltage.size == p.t.size, p.id


def test_used_library_profiles_are_left_out_whether_ids_are_numbers_or_text(setup) -> None:
    fm, truth, lib = setup
    first = [p.id for p, _ in validation_profiles(fm, truth, lib)[2:4]]
    for used in (first, [str(i) for i in first]):
        again = [p.id for p, _ in validation_profiles(fm, truth, lib, used)[2:4]]
        assert not set(map(str, again)) & set(map(str, first))
