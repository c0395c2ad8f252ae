"""Calibration jobs that drive the devices outside a run: the cameras' poses from a pattern of
robot moves (cameras_robot, camera_run, camera_pattern, camera_observations), and the
identification of a thermal model from recorded runs (identify_run). They use the run machinery
(daemon.run), storage and the pure core; the commands call them.
"""
