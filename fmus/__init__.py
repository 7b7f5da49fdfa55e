"""C FMUs of the project (kinematic odometry, FMI 2.0 and 3.0); see fmus/README.md and fmus/build.py."""
