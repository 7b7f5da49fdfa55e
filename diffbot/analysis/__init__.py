"""What a run's messages come to: each scenario's metrics, CSV and plots (runs.py and its
per-scenario modules), a sweep's plots (sweep_plots.py), the plotting setup (plots.py) and
the numbers a scenario is judged by (bands.py: no plotting library)."""
