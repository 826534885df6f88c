"""`mousedom replay --umbmark` emits RUNS.csv rows that `mousedom umbmark` scores."""

from __future__ import annotations

import json
import math

import pytest
from capture_helpers import evemu_captures
from conftest import run_mousedom

from mousedom.fusion import sim


def write_run(tmp_path, cw: bool, rig: sim.Rig) -> list[str]:
    res = sim.simulate(rig, sim.umbmark_square(cw=cw, side=1.0, speed=0.5, turn_rate=1.0))
    return evemu_captures(tmp_path, res, f"{'cw' if cw else 'ccw'}-")


def _score(tmp_path, rig: sim.Rig, config_text: str, tag: str) -> tuple[dict, list[str]]:
    """Both UMBmark runs of ``rig`` replayed with ``config_text``, scored by ``umbmark``:
    (its JSON, the RUNS.csv lines)."""
    config = tmp_path / f"{tag}.yaml"
    config.write_text(config_text)
    runs = tmp_path / f"{tag}-runs.csv"
    for cw in (True, False):
        capture_args = write_run(tmp_path, cw, rig)
        direction = "cw" if cw else "ccw"
        proc = run_mousedom(
            "replay", "--config", str(config), *capture_args,
            "--umbmark", direction, "--umbmark-csv", str(runs),
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        printed = run_mousedom(
            "replay", "--config", str(config), *capture_args, "--umbmark", direction
        )
        assert printed.stdout.startswith(f"{direction},")
    lines = runs.read_text().splitlines()
    score = run_mousedom("umbmark", str(runs), "--json")
    assert score.returncode == 0, score.stderr
    return json.loads(score.stdout), lines


def test_rows_from_replay_score_the_cpi_error(tmp_path):
    rig = sim.three_mouse_rig()
    # The robot believes 2 % fewer counts per inch than the mice give on the 'left' one:
    # a systematic error that shows in both directions, where the online scales are off
    # (on, they correct it: below).
    text = sim.rig_yaml(rig, cpi={"left": (441.0, 441.0)})
    result, lines = _score(tmp_path, rig, text + "robust:\n  learn_scale: false\n", "off")
    assert lines[0] == "direction,dx,dy"
    assert [ln.split(",")[0] for ln in lines[1:]] == ["cw", "ccw"]
    cw = [float(v) for v in lines[1].split(",")[1:]]
    assert result["cw"]["r"] == pytest.approx(math.hypot(*cw), abs=2e-6)
    # A 2 % CPI error on one of three mice on a 1 m square: centimetres, not millimetres.
    assert 0.005 < result["e_max_syst"] < 0.5
    # The online scales (the default) learn that mouse's CPI and give back what it turned
    # and moved before they knew (docs/calibration.md): UMBmark then sees a fraction of it.
    learnt, _ = _score(tmp_path, rig, text, "on")
    assert learnt["e_max_syst"] < 0.2 * result["e_max_syst"], (learnt, result)


def test_bad_true_end_is_a_clear_error(tmp_path):
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(sim.three_mouse_rig()))
    capture_args = write_run(tmp_path, True, sim.three_mouse_rig())
    proc = run_mousedom(
        "replay", "--config", str(config), *capture_args, "--umbmark", "cw", "--true-end", "1;2"
    )
    assert proc.returncode == 2
    assert "--true-end: expected X,Y" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("true_end", ["20000,0", "0,-1e5", "1e300,1"])
def test_a_row_umbmark_would_refuse_is_not_written(tmp_path, true_end):
    """A true end in millimetres (or any end error past umbmark's bound, 1e4 m) made a row
    that `mousedom umbmark`, and every later `--umbmark-csv` append, then refused: the
    runs already in the file could no longer be scored.  No row is written, exit 2."""
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(sim.three_mouse_rig()))
    runs = tmp_path / "runs.csv"
    runs.write_text("direction,dx,dy\nccw,0.01,0.02\n")
    capture_args = write_run(tmp_path, True, sim.three_mouse_rig())
    proc = run_mousedom(
        "replay", "--config", str(config), *capture_args, "--umbmark", "cw",
        "--true-end", true_end, "--umbmark-csv", str(runs),
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "beyond 10000 m" in proc.stderr and "no row written" in proc.stderr, proc.stderr
    assert runs.read_text() == "direction,dx,dy\nccw,0.01,0.02\n"
    proc = run_mousedom(
        "replay", "--config", str(config), *capture_args, "--umbmark", "cw",
        "--true-end", true_end,
    )  # fmt: skip
    assert proc.returncode == 2 and not proc.stdout.startswith("cw,"), proc.stdout


@pytest.mark.parametrize(
    "existing, error",
    [
        ("foo,bar\n1,2\n", "header must have the columns direction,dx,dy"),
        ("dx,direction,dy\n", "its header has the columns dx,direction,dy"),
        ("direction,dx,dy\nsideways,0.1,0.2\n", ":2: direction: must be cw or ccw"),
        ("direction,dx,dy\ncw,0.1\n", ":2: 2 fields"),
        ("direction,dx,dy\n\xff\n", "not UTF-8"),
    ],
)
def test_a_row_is_not_appended_to_a_file_umbmark_could_not_read(tmp_path, existing, error):
    """Appended, the row would join another table or a file `mousedom umbmark` refuses:
    the runs in it would be buried.  The file is left as it was."""
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(sim.three_mouse_rig()))
    runs = tmp_path / "runs.csv"
    runs.write_bytes(existing.encode("utf-8", "surrogateescape").replace(b"\xc3\xbf", b"\xff"))
    before = runs.read_bytes()
    capture_args = write_run(tmp_path, True, sim.three_mouse_rig())
    proc = run_mousedom(
        "replay", "--config", str(config), *capture_args,
        "--umbmark", "cw", "--umbmark-csv", str(runs),
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert error in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert runs.read_bytes() == before


@pytest.mark.parametrize("last_newline", [True, False])
def test_rows_appended_to_runs_keep_each_run_on_its_line(tmp_path, last_newline):
    """A RUNS.csv written by hand or by another tool may end without a newline: the row
    starts a line of its own, and `mousedom umbmark` reads every run, the old and the new.
    The header may follow comments and be spaced and capitalised (umbmark reads it so)."""
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(sim.three_mouse_rig()))
    runs = tmp_path / "runs.csv"
    runs.write_text("# by hand\nDirection , dx,dy\nccw,0.01,0.02" + ("\n" if last_newline else ""))
    for cw in (True, False):
        capture_args = write_run(tmp_path, cw, sim.three_mouse_rig())
        proc = run_mousedom(
            "replay", "--config", str(config), *capture_args,
            "--umbmark", "cw" if cw else "ccw", "--umbmark-csv", str(runs),
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
    lines = runs.read_text().splitlines()
    assert lines[:3] == ["# by hand", "Direction , dx,dy", "ccw,0.01,0.02"]
    assert [ln.split(",")[0] for ln in lines[3:]] == ["cw", "ccw"]
    score = run_mousedom("umbmark", str(runs), "--json")
    assert score.returncode == 0, score.stderr
    # the ccw centroid is the mean of the old run and the new one
    new_ccw = [float(v) for v in lines[4].split(",")[1:]]
    ccw = json.loads(score.stdout)["ccw"]
    assert ccw["x"] == pytest.approx((0.01 + new_ccw[0]) / 2, abs=1e-6)
    assert ccw["y"] == pytest.approx((0.02 + new_ccw[1]) / 2, abs=1e-6)


@pytest.mark.parametrize("cw", [True, False])
def test_a_run_under_the_other_directions_label_is_refused(tmp_path, cw):
    """The replay's heading says which way the square went (-360 or +360 degrees): a row
    labelled the other way would land in the wrong centre of gravity without a word (2 of
    2 mislabelled runs were taken).  Exit 2, nothing appended; the right label writes."""
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(sim.three_mouse_rig()))
    capture_args = write_run(tmp_path, cw, sim.three_mouse_rig())
    runs = tmp_path / "runs.csv"
    wrong, right = ("ccw", "cw") if cw else ("cw", "ccw")
    proc = run_mousedom("replay", "--config", str(config), *capture_args,
                        "--umbmark", wrong, "--umbmark-csv", str(runs))  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"it is a {right} run" in proc.stderr and not runs.exists()
    proc = run_mousedom("replay", "--config", str(config), *capture_args,
                        "--umbmark", right, "--umbmark-csv", str(runs))  # fmt: skip
    assert proc.returncode == 0 and "UMBmark square turns" not in proc.stderr, proc.stderr
    assert runs.read_text().splitlines()[1].startswith(f"{right},")


def test_a_run_that_is_no_square_is_said_and_written(tmp_path):
    rig = sim.three_mouse_rig()
    res = sim.simulate(rig, sim.sequence(sim.pause(0.3), sim.straight(0.5, 0.3), sim.pause(0.3)))
    capture_args = evemu_captures(tmp_path, res, "line-")
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(rig))
    proc = run_mousedom("replay", "--config", str(config), *capture_args, "--umbmark", "cw")
    assert proc.returncode == 0 and proc.stdout.startswith("cw,")
    assert "turned +0 degrees in all" in proc.stderr, proc.stderr
