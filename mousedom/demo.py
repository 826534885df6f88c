"""The demo of ``mousedom run --demo``: the bundled capture of a simulated rig.

``mousedom/data/demo-rig.yaml`` describes a three-mouse rig whose mice replay
``demo-rig.mdcap``; the daemon replays it at real-time pace, in a loop, so that a machine
without mice shows the real daemon publishing a moving pose.
"""

from __future__ import annotations

from pathlib import Path

from mousedom.config import Config, load_config

DATA = Path(__file__).resolve().parent / "data"
DEMO_CONFIG = DATA / "demo-rig.yaml"


def demo_config() -> Config:
    """The demo rig's config, its replay paths resolved inside the installed package."""
    return load_config(DEMO_CONFIG)
