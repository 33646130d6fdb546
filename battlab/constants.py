"""Physical constants (CODATA 2018), SI units."""

F = 96485.33212  # Faraday constant [C/mol]
R_GAS = 8.314462618  # gas constant [J/(mol K)]
