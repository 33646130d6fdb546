"""Reaction kinetics and film: the charge-transfer reaction at the particle surface (Butler–Volmer, A17–A20: the
rate constants k±) and the resistance of the surface film in series with it (R_f±). The base model expresses them
fully; their fix is a refit. (A film resistance and a series contact resistance look alike on full-cell voltage: see
:mod:`battlab.causes.contact_resistance`.)"""

from __future__ import annotations

from battlab.causes.cause import Cause, Evidence

CAUSE = Cause(
    key="kinetics",
    title="reaction kinetics and film",
    mechanism="charge transfer at the particle surface and the resistance of its surface film",
    informed_by=Evidence(
        "pulse",
        "short pulses of several amplitudes at several SOCs (the charge-transfer overpotential is nonlinear in the "
        "current, a film's is linear)",
    ),
    base=("k_n", "k_p", "R_f_n", "R_f_p"),
    validated_by="the base model against PyBaMM's DFN (tests/battlab/model/test_model_pybamm.py)",
    separates={
        "contact_resistance": "short pulses at two ambient temperatures (the charge transfer follows the kinetics' "
        "Arrhenius law, as a real cell's film resistance does; a series resistance barely changes)"
    },
)
