"""The UR e-Series emulator (issue 31): RTDE, the Dashboard Server and the robot-side program."""
