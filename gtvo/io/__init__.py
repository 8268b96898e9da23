"""The edges where files are written and read: trajectory files, a run's outputs, plots, atomic writes."""
