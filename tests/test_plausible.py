"""Config values that look like the wrong unit (issue 29): a warning with file, line, key,
the value as read and the value probably meant; never an error, never on ordinary rigs."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mousedom.config import parse_config
from mousedom.plausible import CPI_RANGE, MAX_MOUNT_M, suspects

RIG = """\
rate_hz: 100
model: lsq
mice:
  a:
    cpi: {cpi}
    mount: {{x: {x}, y: {y}, yaw: {yaw}}}
  b:
    cpi: 800
    mount: {{x: -0.1, y: 0.0, yaw: 0}}
"""


@given(
    cpi=st.floats(CPI_RANGE[0], CPI_RANGE[1]),
    x=st.floats(-MAX_MOUNT_M, MAX_MOUNT_M),
    y=st.floats(-MAX_MOUNT_M, MAX_MOUNT_M),
    yaw=st.one_of(st.integers(-360, 360).map(float), st.floats(6.3, 360.0)),
)
def test_ordinary_rigs_get_no_warning(cpi, x, y, yaw):
    assert suspects([("a", cpi, cpi, x, y, yaw)]) == []


MM = "from the body origin: if that is millimetres,"
CPI = "counts per inch is outside 100-30000, what mice report; if that is counts per"


@pytest.mark.parametrize("cpi, x, y, yaw, key, says", [
    (800, 0.1, 135, 0, "mice.a.mount.y", f"135 m {MM} 0.135 m"),
    (800, -250, 0.05, 0, "mice.a.mount.x", f"-250 m {MM} -0.25 m"),
    (800, 0.1, 0.0, 1.5708, "mice.a.mount.yaw",
     "1.5708 is read as degrees; if it is radians, that is 90 degrees"),
    (31496, 0.1, 0.0, 0, "mice.a.cpi", f"31496 {CPI} metre, 800 CPI"),
    (31.5, 0.1, 0.0, 0, "mice.a.cpi", f"31.5 {CPI} millimetre, 800 CPI"),
])  # fmt: skip
def test_a_value_in_the_wrong_unit_is_said_with_its_line_and_key(cpi, x, y, yaw, key, says):
    cfg = parse_config(RIG.format(cpi=cpi, x=x, y=y, yaw=yaw), "rig.yaml", need_sources=False)
    (w,) = cfg.warnings
    line = 5 if key.endswith("cpi") else 6
    assert w.startswith(f"rig.yaml:{line}: {key}: {says}"), w
    assert math.isfinite(cfg.mice[0].cpi_x)  # the config stands as written


def test_check_config_prints_them_and_exits_0(tmp_path):
    from conftest import run_mousedom

    p = tmp_path / "rig.yaml"
    p.write_text(RIG.format(cpi=800, x=0.1, y=135, yaw=0))
    r = run_mousedom("check-config", "--config", str(p), "--no-sources")
    assert r.returncode == 0, r.stderr
    assert f"mousedom: warning: {p}:6: mice.a.mount.y: 135 m" in r.stderr
