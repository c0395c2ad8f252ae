"""The command-line jobs (``thermocomp run``, ``identify``, ``calibrate ...``, ``devices``): each
module parses its options (cheaply: ``--help`` imports no numeric stack) and calls the service,
the calibration jobs or the pure core. Nothing below imports a command; api/cli.py lists them.
"""
