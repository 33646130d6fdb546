"""Data files: simulation results and logged data as BDF CSV and HDF5."""
