"""The pure fusion engine: units, geometry, models, integrators, covariance, the tracker.

No I/O and no clock: time is data, so replay (millions of windows) and the daemon (a few at
a time) run the same code.  Imports nothing from sources, capture, service or commands
(tests/test_layout.py holds it)."""
