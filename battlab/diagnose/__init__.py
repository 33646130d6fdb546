"""Diagnosis: where the simulation disagrees with measured data, which model extension explains it, and what the
extension buys on data it was not fitted to.

- :mod:`battlab.diagnose.residuals`: the residual against time, SOC, current, direction, rate of change,
  temperature, charge passed, time since the last rest and frequency; whiteness against the noise model;
- :mod:`battlab.diagnose.score`: score (Lagrange-multiplier) tests of each extension at the fitted base model,
  robust to correlated model error, calibrated on null cases;
- :mod:`battlab.diagnose.directions`: the tests' inputs from the model, each catalog extension's exact
  sensitivities at its "off" values beside the base parameters'.
"""
