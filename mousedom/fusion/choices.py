"""The names a rig config chooses from: the fusion's motion models and integrators.

Stated here once, for ``fusion.models``, ``fusion.integrate``, the config's checks and the
CLI's choices.  A leaf that imports nothing (``config`` may import it: tests/test_layout.py).
"""

from __future__ import annotations

MODELS = ("lsq", "diff-drive", "bonarini")
INTEGRATORS = ("exact", "taylor", "euler", "midpoint")
# What a gyro's heading is made of (config's gyro.use; fusion/gyro.py): the gyro and the
# mice together, the gyro alone, the mice alone (the gyro's bias is learnt all the same).
GYRO_USES = ("both", "gyro", "mice")
GYRO = "gyro"  # the gyro's name where sensors are named (Tracker.set_live, SOURCE)
