"""`mousedom replay --umbmark` emits RUNS.csv rows that `mousedom umbmark` scores."""

from __future__ import annotations

import json
import math

import pytest
from conftest import run_mousedom

from mousedom.capture.evemu import format_evemu
from mousedom.fusion import sim


def write_run(tmp_path, cw: bool, rig: sim.Rig) -> list[str]:
    res = sim.simulate(rig, sim.umbmark_square(cw=cw, side=1.0, speed=0.5, turn_rate=1.0))
    args = []
    for name, r in res.reports.items():
        path = tmp_path / f"{'cw' if cw else 'ccw'}-{name}.evemu"
        path.write_text(format_evemu(r.t, r.dx, r.dy, name=name))
        args += ["--capture", f"{name}={path}"]
    return args


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
