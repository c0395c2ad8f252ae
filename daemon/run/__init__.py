"""The run machinery: one run from its start to its final state.

The session (the only code that changes a run's state), its start, the fixed-step scheduler,
the sensors, the events and the frozen read model the API reads, the worker pools, and the run
kinds with their step pipelines: ``two_link/`` (the thesis's bench) and ``arm/`` (a whole arm
playing a duty cycle). It imports storage, the pure core and the drivers; never the service
facade (daemon/service.py), the commands or the API.
"""
