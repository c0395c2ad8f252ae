"""The whole arm (issue 20): kinematics, the arm's thermal network, motor heat from motion, the
tool-pose error of a warm arm and its 6-DOF correction. Pure numeric core: no I/O, no asyncio.

``types`` holds the values the pieces pass to one another (shared contract of issue 20).
"""
