"""The running service: scheduler, runs, recording, and the pure numeric core.

Subpackages ``model``, ``vision`` and ``analysis`` are pure (no I/O) and may be imported by
any layer; everything else here may import ``drivers`` and ``config`` but never ``api``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("thermocomp")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
