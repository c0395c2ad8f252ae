"""Storage: the run database (SQLite, WAL) and what is written from it.

The recorder and its step record, exports (CSV, JSON, Parquet) and run reports with their
worker process. Imports only the pure core (daemon.analysis) and the standard library: the run
machinery (daemon.run) writes through it, never the other way round.
"""
