"""Device drivers: camera, infrared reader, robot; a Protocol each, real and simulated.

Imports only ``config`` and the pure core (``daemon.model``, ``daemon.vision``); never the rest
of ``daemon`` or ``api``.
"""
