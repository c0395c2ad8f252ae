"""Run kind "followed" (issue 27): the robot plays its own program; the daemon follows it and
writes corrections (daemon/run/followed/kind.py)."""
