"""How far the summary trusts an invariant's interval: a bound in its electrode's orbit or an interval that runs to
the bounds' range makes it untrusted, with why; an interior, informed invariant of a converged fit stays trusted."""

from __future__ import annotations

import math

import numpy as np

from battlab.identify.fit_summary import fit_caveats, invariant_caveats
from battlab.identify.statistics import Estimate, Statistics


def estimate(name: str, value: float, at_bound: str | None = None) -> Estimate:
    return Estimate(name, value, 0.5, 0.01, None, (value * 0.9, value * 1.1), None, at_bound, set_identified=True)


ORBIT_N = [estimate("R_s_n", 2e-5), estimate("D_s_n", 2.6e-14), estimate("R_f_n", 1e-4)]


def test_an_electrodes_invariants_are_conditional_on_a_bound_in_its_orbit() -> None:
    k_at_bound = [*ORBIT_N, estimate("k_n", 7.5e-5, at_bound="lower")]
    why = ["k_n at its lower bound: the interval is conditional on it"]
    assert invariant_caveats("kappa_n", (3.5, 4.0), k_at_bound) == why
    # tau_n and rho_n do not contain k_n, but the fit puts into them what the bound denies kappa_n
    assert invariant_caveats("tau_n", (1.5e4, 1.6e4), k_at_bound) == why
    assert invariant_caveats("rho_n", (1.9e-9, 2.1e-9), k_at_bound) == why
    # the other electrode's are not
    p_free = [estimate("R_s_p", 2e-5), estimate("D_s_p", 6e-14), estimate("k_p", 1e-3), estimate("R_f_p", 4e-4)]
    assert invariant_caveats("rho_p", (7e-9, 9e-9), [*k_at_bound, *p_free]) == []


def test_an_invariant_interval_that_runs_to_the_bounds_range_is_not_informed_there() -> None:
    free = [*ORBIT_N, estimate("k_n", 1e-4)]
    # kappa_n = k_n / R_s_n ranges over [7.5e-5 / 1e-4, 7.5e-3 / 1e-6] = [0.75, 7500] within the bounds
    assert invariant_caveats("kappa_n", (2.0, 7500.0), free) == [
        "its interval runs to the range the bounds allow: the data do not inform it there"
    ]
    assert invariant_caveats("kappa_n", (0.75, 30.0), free)
    assert invariant_caveats("kappa_n", (4.0, 6.0), free) == []


def test_a_correlated_residual_is_model_error_whatever_s2_says() -> None:
    st = Statistics(("R_s_n",), np.array([0.5]), 10_001, 10_000, 1.96, None, None, None, 1.3, 10.0)
    assert fit_caveats(True, st) == []  # s² 1.3: no caveat from s² alone
    (why,) = fit_caveats(True, st, (0.12, 10_000))
    assert "lag-1 autocorrelation 0.12" in why and "0 ± 0.01" in why
    assert fit_caveats(True, st, (0.02, 10_000)) == []  # small: within what eq. 46 tolerates
    assert fit_caveats(True, st, (0.2, 100)) == []  # 2 standard errors of white noise: not shown to be correlated
    assert fit_caveats(True, st, (math.nan, 0)) == []


def test_the_autocorrelation_pairs_only_neighbours_that_are_both_scored() -> None:
    from battlab.identify.experiments import Experiment
    from battlab.identify.problem import residual_autocorrelation
    from protocols.profile import Profile

    prof = Profile(np.arange(5.0), np.zeros(5), id="p")
    mask = np.array([True, True, False, True, True])  # sample 2 is not scored: no pair across it
    e = Experiment("e", prof, np.zeros(5), 0.5, 1.0, mask=mask)
    rho, n = residual_autocorrelation([e], [np.array([1.0, -1.0, 100.0, 1.0, -1.0])])
    assert n == 2 and rho == -0.5  # pairs (0, 1) and (3, 4); the residual of 100 is left out
