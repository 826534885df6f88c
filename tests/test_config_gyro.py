"""The config's ``gyro:`` section: its defaults, and each mistake named by file, line, key."""

from __future__ import annotations

import math

import pytest

from mousedom.config import ConfigError, GyroConfig, load_config, parse_config

MICE = """\
mice:
  left:
    cpi: 450
    mount: {x: 0.0, y: 0.135, yaw: 0.0}
    replay: left.events
  right:
    cpi: 450
    mount: {x: 0.0, y: -0.135, yaw: 0.0}
    replay: right.events
"""
GOOD = (
    MICE
    + """\
gyro:
  name: mpu6050
  axis: z
  sign: -1
  sample_hz: 200
  noise: 1.0e-4
  use: gyro
"""
)


def test_good_gyro_section(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(GOOD)
    g = load_config(path).gyro
    assert g == GyroConfig(name="mpu6050", axis="z", sign=-1, sample_hz=200.0, noise=1e-4,
                           use="gyro")  # fmt: skip
    with pytest.raises(AttributeError):
        g.sign = 1  # frozen


def test_defaults_and_no_gyro():
    assert parse_config(MICE).gyro is None
    g = parse_config(MICE + "gyro: {path: /sys/bus/iio/devices/iio:device0}\n").gyro
    assert g.path == "/sys/bus/iio/devices/iio:device0" and g.name is None
    assert (g.axis, g.sign, g.sample_hz, g.use) == ("z", 1, None, "both")
    # MPU-6050 datasheet: 0.005 deg/s/sqrt(Hz)
    assert g.noise == pytest.approx(math.radians(0.005)) and g.noise == GyroConfig().noise
    # a config used for replay may leave out where the gyro comes from, as mice may
    g = parse_config(MICE + "gyro: {use: both}\n", need_sources=False).gyro
    assert g == GyroConfig()


@pytest.mark.parametrize(
    "old, new, line, key, words",
    [
        ("  axis: z\n", "  axis: w\n", 12, "gyro.axis", "must be one of x, y, z, got 'w'"),
        ("  sign: -1\n", "  sign: 2\n", 13, "gyro.sign", "must be 1 or -1"),
        ("  sign: -1\n", "  sign: -1.0\n", 13, "gyro.sign", "must be an integer"),
        ("  sample_hz: 200\n", "  sample_hz: 0\n", 14, "gyro.sample_hz", "between 0.1"),
        ("  sample_hz: 200\n", "  sample_hz: fast\n", 14, "gyro.sample_hz", "must be a number"),
        ("  noise: 1.0e-4\n", "  noise: -1\n", 15, "gyro.noise", "positive"),
        ("  noise: 1.0e-4\n", "  noise: 5\n", 15, "gyro.noise", "between 0 and 1"),
        ("  use: gyro\n", "  use: wheels\n", 16, "gyro.use", "both, gyro, mice"),
        ("  use: gyro\n", "  rate_hz: 200\n", 16, "gyro.rate_hz", "unknown key"),
        ("  name: mpu6050\n", "  nmae: mpu6050\n", 11, "gyro.nmae", "did you mean name?"),
        ("  name: mpu6050\n", "  name: 6050\n", 11, "gyro.name", "must be a string"),
        ("  name: mpu6050\n", '  name: ""\n', 11, "gyro.name", "must not be empty"),
        ("  name: mpu6050\n", "  path: iio:device0\n", 11, "gyro.path", "absolute path"),
        ("  name: mpu6050\n", "", 10, "gyro", "needs name"),
    ],
)
def test_mistakes_name_file_line_and_key(tmp_path, old, new, line, key, words):
    path = tmp_path / "rig.yaml"
    assert old in GOOD
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {key}:"), msg
    assert words in msg


def test_gyro_must_be_a_mapping(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(MICE + "gyro: mpu6050\n")
    with pytest.raises(ConfigError, match=rf"^{path}:10: gyro: must be a mapping, got 'mpu6050'"):
        load_config(path)


def test_every_gyro_mistake_in_one_run(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(MICE + "gyro:\n  name: mpu6050\n  axis: q\n  sygn: 1\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    lines = str(err.value).splitlines()
    assert lines[0].startswith(f"{path}:12: gyro.axis:"), lines
    assert lines[1].startswith(f"{path}:13: gyro.sygn: unknown key (did you mean sign?"), lines
