"""The campaign: the whole loop (capacity check, OCV test, equilibrium, library, sweep, groups, noise model,
designs, experiments, fits, conventional baseline, validation, diagnosis, BPX export, report) as resumable
stages in one directory."""
