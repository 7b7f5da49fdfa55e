"""Running a scenario: scenario files (scenario.py, scenarios/), a scenario's run and its
command line (scenario_run.py, launcher.py), placement on a Ray cluster (placement.py), the
member commands (members.py), the run's observer, and the Zenoh router and TLS
certificates for several machines (router.py, certs.py, configs/)."""
