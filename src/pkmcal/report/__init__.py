"""Reports and plots. Plotting lives in :mod:`pkmcal.report.plots` (imports matplotlib)."""
