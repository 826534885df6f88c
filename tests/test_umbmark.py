"""UMBmark (Borenstein & Feng): centres of gravity, E_max,syst, RUNS.csv, the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from conftest import run_mousedom

from mousedom.calibrate.umbmark import parse_runs, umbmark, umbmark_row
from mousedom.errors import UserError
from mousedom.fusion import sim

RUNS = """direction,dx,dy
cw,0.10,0.02
cw,0.12,0.04
cw,0.11,0.03
ccw,-0.05,0.01
ccw,-0.07,0.03
"""


def test_centres_of_gravity_and_e_max_syst():
    """Borenstein & Feng: x_c = mean dx, y_c = mean dy per direction, r = |(x_c, y_c)|,
    E_max,syst = max(r_cw, r_ccw)."""
    dirs, err = parse_runs(RUNS, "RUNS.csv")
    res = umbmark(dirs, err)
    assert (res.cw.x, res.cw.y) == pytest.approx((0.11, 0.03))
    assert (res.ccw.x, res.ccw.y) == pytest.approx((-0.06, 0.02))
    assert res.cw.r == pytest.approx(math.hypot(0.11, 0.03))
    assert res.e_max_syst == pytest.approx(res.cw.r)
    doc = res.as_json()
    assert set(doc) == {"e_max_syst", "cw", "ccw"} and set(doc["cw"]) == {"x", "y", "r"}
    assert any("only 3 cw" in w for w in res.warnings)


def test_umbmark_row_is_odometry_minus_truth():
    assert umbmark_row("cw", (1.0, 2.0, 0.3), (0.9, 2.5, 0.0)) == "cw,0.100000,-0.500000"
    with pytest.raises(ValueError):
        umbmark_row("left", (0, 0), (0, 0))
    dirs, err = parse_runs("direction,dx,dy\n" + umbmark_row("ccw", (1, 1), (0, 0)), "r")
    assert dirs == ["ccw"] and err.tolist() == [[1.0, 1.0]]


@pytest.mark.parametrize(
    "text, message",
    [
        ("dir,dx,dy\ncw,0,0\n", "RUNS.csv:1: header must have the columns direction,dx,dy"),
        ("direction,dx,dy\ncw,0,0\nleft,0,0\n", "RUNS.csv:3: direction: must be cw or ccw"),
        ("direction,dx,dy\ncw,0.1,abc\n", "RUNS.csv:2: dy: not a number: 'abc'"),
        ("direction,dx,dy\ncw,0.1\n", "RUNS.csv:2: 2 fields, the header has 3"),
        ("direction,dx,dy\ncw,inf,0\n", "RUNS.csv:2: dx: not a finite number"),
        ("", "RUNS.csv: empty file"),
        # regression: a second dx column was silently ignored
        ("direction,dx,dy,dx\ncw,1,1,3\n", "RUNS.csv:1: column dx appears more than once"),
    ],
)
def test_runs_csv_errors_name_line_and_column(text, message):
    with pytest.raises(UserError) as e:
        parse_runs(text, "RUNS.csv")
    assert message in str(e.value)


def test_umbmark_needs_both_directions():
    with pytest.raises(ValueError, match="no ccw run"):
        umbmark(["cw"], np.zeros((1, 2)))


def test_cli_json_report_and_write(tmp_path):
    runs = tmp_path / "runs.csv"
    runs.write_text("# five each way would be better\n" + RUNS)
    p = run_mousedom("umbmark", str(runs), "--json")
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["e_max_syst"] == pytest.approx(math.hypot(0.11, 0.03), abs=1e-6)
    assert "E_max,syst = 114.0 mm" in p.stderr and "warning: only 2 ccw" in p.stderr
    p = run_mousedom("umbmark", "-", input=RUNS)
    assert p.returncode == 0 and "E_max,syst = 114.0 mm" in p.stdout
    (tmp_path / "rig.yaml").write_text(
        "mice:\n  a: {cpi: 400, mount: {x: 0.1}}\n  b: {cpi: 400, mount: {x: -0.1}}\n"
        "calibration: rig.calib.yaml\n"
    )
    p = run_mousedom("umbmark", str(runs), "--config", str(tmp_path / "rig.yaml"), "--write")
    assert p.returncode == 0, p.stderr
    assert "written to " in p.stderr and "rig.calib.yaml\n" in p.stderr  # where (issue 29)
    cal = yaml.safe_load((tmp_path / "rig.calib.yaml").read_text())
    assert cal["umbmark"]["e_max_syst"] == pytest.approx(0.114018, abs=1e-6)


def test_cli_bad_inputs(tmp_path):
    bad = tmp_path / "runs.csv"
    bad.write_text("direction,dx,dy\ncw,0.1,0.1\n")
    p = run_mousedom("umbmark", str(bad))
    assert p.returncode == 2 and "runs.csv: no ccw run" in p.stderr
    assert "Traceback" not in p.stderr
    p = run_mousedom("umbmark", str(tmp_path / "missing.csv"))
    assert p.returncode == 2 and "missing.csv: file not found" in p.stderr
    p = run_mousedom("umbmark", str(bad), "--write")
    assert p.returncode == 2 and "--write needs --config" in p.stderr


@pytest.mark.parametrize("scale, warned", [(1.0, False), (1000.0, True)])
def test_a_file_in_millimetres_is_warned_of(tmp_path, scale, warned):
    """RUNS.csv is in metres.  The same runs written in millimetres (errors of 20-300, under
    parse_runs' 1e4 bound) were scored 1,000 times too high without a word: now a warning
    names how many runs end beyond the square's side and how far, exit 0 (a broken
    odometry's runs may end that far off)."""
    rng = np.random.default_rng(7)
    rows = [
        f"{d},{dx * scale:.6f},{dy * scale:.6f}"
        for d in ("cw", "ccw")
        for dx, dy in rng.uniform(-0.3, 0.3, (5, 2)) + [0.02, 0.02]
    ]
    runs = tmp_path / "runs.csv"
    runs.write_text("direction,dx,dy\n" + "\n".join(rows) + "\n")
    p = run_mousedom("umbmark", str(runs))
    assert p.returncode == 0, p.stderr
    said = "is it in millimetres?" in p.stderr
    assert said == warned, p.stderr
    if warned:
        assert "10 run(s) end more than 4 m" in p.stderr


def test_umbmark_on_simulated_squares_sees_a_cpi_error():
    """4 m squares on the core simulator and tracker: with the true CPI the systematic
    error is tiny; with a 2 % CPI error on one mouse of two it is large."""
    mice = (
        sim.SimMouse("left", 0.0, 0.135, cpi_x=450, cpi_y=450),
        sim.SimMouse("right", 0.0, -0.135, cpi_x=450, cpi_y=450, phase=0.004),
    )
    rig = sim.Rig(mice)

    def e_max(cpi):
        rows = []
        for cw in (True, False):
            res = sim.simulate(rig, sim.umbmark_square(cw=cw, speed=0.5, turn_rate=1.0), seed=1)
            poses, _ = sim.run_tracker(res, sim.rig_config(rig, cpi))
            final = (poses.x[-1], poses.y[-1])
            true = res.truth(res.motion.starts[-1])[0]
            rows.append(umbmark_row("cw" if cw else "ccw", final, true))
        dirs, err = parse_runs("direction,dx,dy\n" + "\n".join(rows), "sim")
        return umbmark(dirs, err).e_max_syst

    assert e_max(None) < 0.01
    assert e_max({"left": (450, 459), "right": (450, 450)}) > 0.1


def test_cli_reads_a_spreadsheet_csv_with_a_byte_order_mark(tmp_path):
    """Regression: RUNS.csv saved by a spreadsheet (UTF-8 with BOM, CRLF) was refused."""
    runs = tmp_path / "runs.csv"
    runs.write_bytes(b"\xef\xbb\xbf" + RUNS.replace("\n", "\r\n").encode())
    p = run_mousedom("umbmark", str(runs), "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["cw"]["x"] == pytest.approx(0.11)


def test_cli_binary_input_is_one_line_naming_the_byte(tmp_path):
    """Regression: binary garbage on stdin was decoded with surrogates and echoed back as
    a header of mojibake; a file and stdin now both name the first bad byte."""
    garbage = b"direction,dx,dy\ncw,1,1\n\xff\xfe\x00\x81"
    p = run_mousedom("umbmark", "-", input=garbage)
    assert p.returncode == 2 and b"Traceback" not in p.stderr
    assert p.stderr.strip() == b"mousedom: error: <stdin>: byte offset 23: not UTF-8 text"
    (tmp_path / "bin.csv").write_bytes(garbage)
    p = run_mousedom("umbmark", str(tmp_path / "bin.csv"))
    assert p.returncode == 2 and "bin.csv: byte offset 23: not UTF-8 text" in p.stderr


@pytest.mark.parametrize("where", ["header", "row"])
def test_a_field_past_the_csv_limit_is_one_error_with_its_line(where):
    """A field over csv's 131072-character limit raised _csv.Error (issue 11, item 5)."""
    from mousedom.calibrate.reference import parse_reference
    from mousedom.calibrate.umbmark import parse_runs

    huge = "9" * 200_000
    runs = f"direction,dx,dy\ncw,{huge},0\n" if where == "row" else f"direction,dx,{huge}\n"
    with pytest.raises(UserError, match=r"RUNS.csv:\d: not a CSV line"):
        parse_runs(runs, "RUNS.csv")
    ref = f"t,vx,vy,omega\n0,{huge},0,0\n" if where == "row" else f"t,{huge}\n"
    with pytest.raises(UserError, match=r"REF.csv:\d: not a CSV line"):
        parse_reference(ref, "REF.csv")
