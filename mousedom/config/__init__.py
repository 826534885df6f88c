"""Rig configuration: YAML in, frozen validated dataclasses out.

Every mistake becomes one ``ConfigError`` naming the file, the line and the key, e.g.
``rig.yaml:7: mice.left.cpi: must be a positive number, got -3``.  The YAML is parsed to
a node tree first so that each value keeps the line it came from.

A config may reference a calibration file (``calibration: rig.calib.yaml``, relative to
the config).  Values found there (per-mouse CPI and mount) override those of the config;
``mousedom calibrate ... --write`` writes that file, and the daemon rereads it on SIGHUP.
A referenced calibration file that does not exist yet is not an error: nothing has been
calibrated so far.

The modules, one idea each: ``rig`` (the rig's types and their defaults), ``mice`` (the
``mice:`` section and the calibration overlay), ``outputs`` (the server and the optional
outputs), ``gyro`` (the optional IIO gyro), ``load`` (the top level and the file).
Importers use the names below.
"""

from __future__ import annotations

from mousedom.config.load import DEFAULT_CONFIG_PATH, load_config, parse_config
from mousedom.config.outputs import (
    ROS_NAMESPACE,
    ROS_NODE_NAME,
    FoxgloveConfig,
    MetricsConfig,
    Ros2Config,
    ServerConfig,
)
from mousedom.config.rig import (
    Config,
    EvdevMatch,
    GyroConfig,
    GyroRos2,
    Mount,
    MouseConfig,
    RobustConfig,
    SerialSource,
    WheelsConfig,
)
from mousedom.fusion.choices import INTEGRATORS, MODELS
from mousedom.yamldoc import ConfigError

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "INTEGRATORS",
    "MODELS",
    "ROS_NAMESPACE",
    "ROS_NODE_NAME",
    "Config",
    "ConfigError",
    "EvdevMatch",
    "FoxgloveConfig",
    "GyroConfig",
    "GyroRos2",
    "MetricsConfig",
    "Mount",
    "MouseConfig",
    "Ros2Config",
    "RobustConfig",
    "SerialSource",
    "ServerConfig",
    "WheelsConfig",
    "load_config",
    "parse_config",
]
