"""The ``diffbot`` command (cli.py) over packages by concern: runner (child processes, a
pool, Ray), analysis (metrics and plots), envs (the Gymnasium and PettingZoo environments),
launch (a scenario's run), sweep, study and bench (docs/layout.md)."""
