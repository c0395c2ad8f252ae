"""The arm run kind: a whole arm plays its duty cycle; each measured pose gets its correction
and its tool measurement (the player, the poses' references, the arm's step)."""
