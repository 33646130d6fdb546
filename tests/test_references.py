"""The tests' reference packages (PyBaMM, BEEP, batterydf): a missing one skips on a developer's machine and fails
in CI, where a comparison that silently loses its reference would check nothing."""

from __future__ import annotations

import sys

import pytest

from tests.conftest import REFERENCES, reference


@pytest.fixture
def bdf_missing(monkeypatch: pytest.MonkeyPatch) -> None:
    """``import bdf`` raises ImportError (a None entry in sys.modules), whether or not batterydf is installed."""
    monkeypatch.setitem(sys.modules, "bdf", None)


def test_a_missing_reference_fails_in_ci(bdf_missing: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "1")
    with pytest.raises(pytest.fail.Exception, match=r"CI: bdf cannot be imported .*batterydf"):
        reference("bdf")


def test_a_missing_reference_skips_outside_ci(bdf_missing: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="bdf cannot be imported"):
        reference("bdf")


def test_an_installed_reference_is_returned(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", "1")
    fake = type(sys)("beep_fake_for_test")
    monkeypatch.setitem(sys.modules, "beep", fake)
    assert reference("beep") is fake


def test_only_the_listed_packages_are_references() -> None:
    assert set(REFERENCES) == {"pybamm", "beep", "bdf"}
    with pytest.raises(KeyError, match="not a reference package"):
        reference("numpy")
