"""The bundled demo rig (``mousedom run --demo``): a config whose mice replay the bundled
capture of a simulated three-mouse rig (mousedom/data, made by scripts/make_demo.py)."""

from __future__ import annotations

from pathlib import Path

from mousedom.config import Config, load_config

DATA = Path(__file__).resolve().parent / "data"
DEMO_CONFIG = DATA / "demo-rig.yaml"
DEMO_CAPTURE = DATA / "demo-rig.mdcap"


def demo_config() -> Config:
    """The demo rig config; its mice's ``replay:`` entries point at the bundled capture."""
    return load_config(DEMO_CONFIG)
