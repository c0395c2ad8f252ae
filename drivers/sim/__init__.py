"""The simulated bench: the physical truth that the simulated drivers share."""
