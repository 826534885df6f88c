"""The names a rig config chooses from: the fusion's motion models and integrators.

Stated here once, for ``fusion.models``, ``fusion.integrate``, the config's checks and the
CLI's choices.  A leaf that imports nothing (``config`` may import it: tests/test_layout.py).
"""

from __future__ import annotations

MODELS = ("lsq", "diff-drive", "bonarini")
INTEGRATORS = ("exact", "taylor", "euler", "midpoint")
