"""`mousedom calibrate ...` as a real process on captures written to disk."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import run_mousedom

from mousedom.calibrate.synth import SynthMouse, build_motion, mouse_reports, twist_csv
from mousedom.capture.base import DeviceInfo
from mousedom.capture.evemu import format_evemu
from mousedom.capture.native import NativeWriter
from mousedom.sources.base import Reports

EPOCH = 1_700_000_000.0


def write_evemu(path: Path, rep: Reports, t0: float = EPOCH) -> Path:
    """An old-style evemu .events file (E: lines only, epoch times)."""
    path.write_text(format_evemu(np.asarray(rep.t) + t0, rep.dx, rep.dy, version=None))
    return path


def write_native(path: Path, recording: dict[str, Reports]) -> Path:
    devices = [DeviceInfo(name=f"sim {n}", mouse=n) for n in recording]
    with NativeWriter(path, devices, time_base="monotonic") as w:
        for i, rep in enumerate(recording.values()):
            w.motion(i, rep.t, rep.dx.astype(int), rep.dy.astype(int))
        w.sync(max(float(r.t[-1]) for r in recording.values() if len(r.t)))
    return path


def write_config(tmp: Path, mice: dict[str, dict], calibration: bool = True, extra: str = ""):
    doc = {"mice": mice}
    if calibration:
        doc["calibration"] = "rig.calib.yaml"
    text = yaml.safe_dump(doc, sort_keys=False) + extra
    (tmp / "rig.yaml").write_text(text)
    return tmp / "rig.yaml"


def calib(what: str, cfg: Path, *args: str):
    """``mousedom calibrate WHAT --config CFG ARGS...`` as a real process."""
    return run_mousedom("calibrate", what, "--config", str(cfg), *args)


def ok(proc):
    assert proc.returncode == 0, proc.stderr
    return proc


def fails(proc, *needles):
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    for n in needles:
        assert n in proc.stderr, proc.stderr
    return proc


# --------------------------------------------------------------------------- cpi


@pytest.fixture
def cpi_session(tmp_path):
    """Two mice on one sled, 8 pushes of 20 cm; true CPI 455 and 812 along y."""
    motion = build_motion([(0.2 * (-1) ** k, 0, 0, 1.2) for k in range(8)])
    mice = [
        SynthMouse("left", 0, 0.1, cpi_x=450, cpi_y=455, rel_noise=0.005),
        SynthMouse("right", 0, -0.1, cpi_x=800, cpi_y=812, rel_noise=0.005, phase=0.3),
    ]
    files = {
        m.name: write_evemu(tmp_path / f"{m.name}.events", mouse_reports(m, motion, i))
        for i, m in enumerate(mice)
    }
    cfg = write_config(
        tmp_path,
        {
            "left": {"cpi": 400, "mount": {"x": 0, "y": 0.1}},
            "right": {"cpi": 800, "mount": {"x": 0, "y": -0.1}},
        },
    )
    return tmp_path, cfg, files


def test_cpi_json_report_and_write(cpi_session):
    tmp, cfg, files = cpi_session
    caps = [a for n, f in files.items() for a in ("--capture", f"{n}={f}")]
    p = ok(calib("cpi", cfg, *caps, "--distance", "0.2", "--json"))
    doc = json.loads(p.stdout)
    assert set(doc) == {"left", "right"}
    assert set(doc["left"]) == {"axis", "cpi", "stderr", "runs"}
    assert doc["left"]["axis"] == "y" and doc["left"]["runs"] == 8
    assert doc["left"]["cpi"] == pytest.approx(455, rel=3e-3)
    assert doc["right"]["cpi"] == pytest.approx(812, rel=3e-3)
    assert "left: cpi y = " in p.stderr  # the readable report moves to stderr with --json
    p = ok(calib("cpi", cfg, *caps, "--distance", "0.2", "--write"))
    assert "right: cpi y = " in p.stdout and "written to" in p.stderr
    cal = yaml.safe_load((tmp / "rig.calib.yaml").read_text())
    assert cal["mice"]["left"]["cpi"]["y"] == pytest.approx(455, rel=3e-3)
    p = ok(run_mousedom("check-config", "--config", str(cfg), "--no-sources"))
    assert "left: cpi 400/45" in p.stdout  # x as configured, y calibrated


def test_cpi_bad_inputs(cpi_session):
    tmp, cfg, files = cpi_session
    left = f"left={files['left']}"
    fails(
        calib(
            "cpi",
            cfg,
            "--capture",
            left,
            "--distance",
            "0.2",
            "--min-runs",
            "9",
        ),
        "found 8 run(s), need at least 9",
        "--gap",
    )
    fails(
        calib(
            "cpi",
            cfg,
            "--capture",
            f"middle={files['left']}",
            "--distance",
            "0.2",
        ),
        "no mouse 'middle'",
        "left, right",
    )
    fails(
        calib("cpi", cfg, "--capture", "left", "--distance", "0.2"),
        "left: capture file not found",  # FILE alone is allowed: its device names a mouse
    )
    fails(
        calib(
            "cpi",
            cfg,
            "--capture",
            f"left={tmp / 'nope.events'}",
            "--distance",
            "0.2",
        ),
        "nope.events: capture file not found",
    )
    # Pushed sideways but calibrated along y: every run is "no counts along y".
    motion = build_motion([(0, 0.2 * (-1) ** k, 0, 1.2) for k in range(3)])
    side = write_evemu(tmp / "side.events", mouse_reports(SynthMouse("left", 0, 0), motion))
    fails(
        calib(
            "cpi",
            cfg,
            "--capture",
            f"left={side}",
            "--distance",
            "0.2",
        ),
        "mouse left: run 1: no counts along y",
    )
    bad = write_config(
        tmp,
        {"left": {"cpi": 400, "mount": {}}, "right": {"cpi": 400, "mount": {"x": 0.1}}},
        calibration=False,
    )
    fails(
        run_mousedom(
            "calibrate",
            "cpi",
            "--config",
            str(bad),
            "--capture",
            left,
            "--distance",
            "0.2",
            "--write",
        ),
        "--write needs a calibration file",
    )
    fails(
        run_mousedom(
            "calibrate", "cpi", "--config", str(bad), "--capture", left, "--distance", "-1"
        ),
        "must be a length between 0.0001 and 1e7 m",
    )


def test_a_mouse_that_never_moved_is_named(cpi_session):
    tmp, cfg, files = cpi_session
    still = tmp / "still.events"
    still.write_text(f"E: {EPOCH + 1:.6f} 0000 0000 0\nE: {EPOCH + 2:.6f} 0000 0000 0\n")
    fails(
        calib(
            "cpi",
            cfg,
            "--capture",
            f"left={files['left']}",
            "--capture",
            f"right={still}",
            "--distance",
            "0.2",
        ),
        "mouse right: no motion in any run",
    )


def test_run_counts_are_validated(cpi_session):
    """Regression: --min-runs 0/-3 and --runs -3 were accepted; --min-runs 1 printed
    "stderr": NaN (not JSON) with numpy warnings."""
    tmp, cfg, files = cpi_session
    base = ["calibrate", "cpi", "--config", str(cfg), "--capture", f"left={files['left']}"]
    for flag, value in (("--min-runs", "0"), ("--min-runs", "-3"), ("--runs", "-3")):
        fails(run_mousedom(*base, "--distance", "0.2", flag, value), flag, "must be 1 or more")
    fails(run_mousedom(*base, "--distance", "0.2", "--runs", "2.5"), "not a whole number")
    # Regression: --distance 20 (centimetres) gave cpi 4.5 against 400 configured, silently.
    p = ok(run_mousedom(*base, "--distance", "20"))
    assert "mousedom: warning: mouse left: cpi 4.5 is -99% off the configured 400" in p.stderr
    assert "is --distance right (metres: 20 m = 20000 mm)?" in p.stderr
    p = ok(run_mousedom(*base, "--distance", "0.2"))  # 455 vs 400: within 25 %, no warning
    assert "warning" not in p.stderr
    # One push: no standard error, so no answer, whatever --min-runs says.
    one = write_evemu(
        tmp / "one.events",
        mouse_reports(SynthMouse("left", 0, 0.1, 450, 455), build_motion([(0.2, 0, 0, 1.2)])),
    )
    p = fails(
        calib("cpi", cfg, "--capture", f"left={one}",
            "--distance", "0.2", "--min-runs", "1", "--json",
        ),
        "mouse left: 1 run(s), need at least 2 for a standard error",
    )  # fmt: skip
    assert p.stdout == "" and "RuntimeWarning" not in p.stderr


def test_mounts_window_and_min_runs_are_validated(mounts_session):
    """Regression: --window nan was a traceback, --window -1 silently meant 0, and mounts
    ignored --min-runs."""
    tmp, cfg, caps, ref, _, _ = mounts_session
    mounts = ["calibrate", "mounts", "--config", str(cfg), *caps, "--reference", str(ref)]
    for value in ("nan", "-1", "inf", "x"):
        fails(run_mousedom(*mounts, "--window", value), "--window")
    # Regression: --window 1e-9 asked for 2e9 windows (a MemoryError traceback).
    fails(
        run_mousedom(*mounts, "--window", "1e-9"),
        "--window 1e-09 s is shorter than one report period (8 ms, mouse a)",
    )
    ok(run_mousedom(*mounts, "--window", "0.008"))
    # mounts honours --min-runs too (the session has 5 runs).
    fails(run_mousedom(*mounts, "--min-runs", "6"), "found 5 run(s), need at least 6")


def test_runs_not_split_say_so(cpi_session):
    """Regression: with --gap longer than the pauses, all pushes forth and back are one run
    whose counts add up to nothing, and the message said the mouse never moved."""
    tmp, cfg, files = cpi_session
    fails(
        calib("cpi", cfg, "--capture", f"left={files['left']}",
            "--distance", "0.2", "--gap", "100", "--min-runs", "1",
        ),
        "mouse left: its motion adds up to nothing in every run (runs: 1)",
        "--gap",
    )  # fmt: skip


def test_cpi_report_shows_a_small_standard_error(tmp_path):
    """Regression: the readable report rounded the standard error to one decimal, so a
    noise-free session printed '+- 0.0'; it now has two."""
    motion = build_motion([(0.2 * (-1) ** k, 0, 0, 1.2) for k in range(6)])
    rep = mouse_reports(SynthMouse("m", 0, 0, cpi_x=450, cpi_y=455, rel_noise=0.001), motion)
    f = write_evemu(tmp_path / "m.events", rep)
    cfg = write_config(
        tmp_path, {"m": {"cpi": 450, "mount": {"x": 0.1}}}, False, "model: diff-drive\n"
    )
    base = ["calibrate", "cpi", "--config", str(cfg), "--capture", f"m={f}", "--distance", "0.2"]
    doc = json.loads(ok(run_mousedom(*base, "--json")).stdout)["m"]
    assert 0 < doc["stderr"] < 0.5  # would print as "+- 0.0" or "+- 0.1" before
    text = ok(run_mousedom(*base)).stdout
    assert f"m: cpi y = {doc['cpi']:.2f} +- {doc['stderr']:.2f} from 6 pushes" in text


def test_cpi_warns_when_runs_disagree(tmp_path):
    # Two short pushes among long ones: not bumps (over 25 % of the median), but 10 % off.
    motion = build_motion(
        [
            (0.2, 0, 0, 1.2),
            (-0.2, 0, 0, 1.2),
            (0.18, 0, 0, 1.2),
            (-0.2, 0, 0, 1.2),
            (0.003, 0, 0, 0.5),
        ]
    )
    f = write_evemu(tmp_path / "m.events", mouse_reports(SynthMouse("m", 0, 0), motion))
    cfg = write_config(
        tmp_path, {"m": {"cpi": 1000, "mount": {}}, "n": {"cpi": 1000, "mount": {"x": 0.1}}}
    )
    p = ok(calib("cpi", cfg, "--capture", f"m={f}", "--distance", "0.2"))
    assert "warning: mouse m: runs disagree by more than 2%" in p.stderr
    assert "run 3" in p.stderr
    assert "left out run 5" in p.stderr and "a bump" in p.stderr  # said, not silent
    # Such a mean is not stored by --write unless --force says so.
    base = ["calibrate", "cpi", "--config", str(cfg), "--capture", f"m={f}", "--distance", "0.2"]
    fails(run_mousedom(*base, "--write"), "not written: the runs disagree", "--force")
    assert not (tmp_path / "rig.calib.yaml").exists()
    ok(run_mousedom(*base, "--write", "--force"))
    assert "m:" in (tmp_path / "rig.calib.yaml").read_text()


def test_runs_are_numbered_as_in_the_session_after_a_bump_is_left_out(tmp_path):
    """Run 2 is a bump (left out, said) and run 5 a push 10 % long: the warning, the list
    per run and an error all number the runs as the session does (the note about the bump
    does), not within the runs kept, which named run 4 for the push that was run 5."""
    long = 0.2 * 1.1
    moves = [(0.2, 0, 0, 1.2), (-0.01, 0, 0, 0.5), (0.2, 0, 0, 1.2), (-0.2, 0, 0, 1.2),
             (long, 0, 0, 1.2), (-0.2, 0, 0, 1.2)]  # fmt: skip
    f = write_evemu(tmp_path / "m.events",
                    mouse_reports(SynthMouse("m", 0, 0), build_motion(moves)))  # fmt: skip
    cfg = write_config(
        tmp_path, {"m": {"cpi": 1000, "mount": {}}, "n": {"cpi": 1000, "mount": {"x": 0.1}}}
    )
    p = ok(calib("cpi", cfg, "--capture", f"m={f}", "--distance", "0.2"))
    assert "left out run 2" in p.stderr
    said = r"runs disagree by more than 2% \(mean [0-9.]+; run 5: 1100"
    assert re.search(said, p.stderr), p.stderr
    assert re.search(r"per run: run 1: 1000\.0, run 3: 1000\.0, run 4: 1000\.0, run 5: 110\d\.\d, "
                     r"run 6: 1000\.0", p.stdout), p.stdout  # fmt: skip
    # the same session with run 5 pushed 25 degrees askew: the error names run 5
    skew = math.radians(25)
    moves[4] = (0.2 * math.cos(skew), 0.2 * math.sin(skew), 0, 1.2)
    f = write_evemu(tmp_path / "m.events",
                    mouse_reports(SynthMouse("m", 0, 0), build_motion(moves)))  # fmt: skip
    fails(calib("cpi", cfg, "--capture", f"m={f}", "--distance", "0.2"),
          "mouse m: run 5: the push was 25 deg off")  # fmt: skip


def test_cpi_on_a_real_recording(external_captures, tmp_path):
    """The PS/2 recording was no calibration session, but it must load and split into
    runs at its pauses exactly as an independent count of its gaps says."""
    f = external_captures / "evemu-devices__PS2_Generic_Mouse.events"
    stamps = []
    frame_moves = False
    for line in f.read_text().splitlines():
        _, t, typ, code, value = line.split()
        if typ == "0002" and int(value):
            frame_moves = True
        if typ == "0000" and code == "0000":
            if frame_moves:
                stamps.append(float(t))
            frame_moves = False
    runs = 1 + int(np.sum(np.diff(stamps) > 0.5))
    cfg = write_config(
        tmp_path,
        {"m": {"cpi": 1000, "mount": {}}, "n": {"cpi": 1000, "mount": {"x": 0.1}}},
        calibration=False,
    )
    p = calib(
        "cpi",
        cfg,
        "--capture",
        f"m={f}",
        "--distance",
        "0.1",
        "--json",
        "--axis",
        "x",
        "--min-runs",
        "2",
    )
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    left_out = p.stderr.count("left out run")
    assert doc["m"]["runs"] + left_out == runs
    assert doc["m"]["cpi"] > 0


# --------------------------------------------------------------------------- distance


def _pair_drive(tmp_path: Path, moves, mounts: dict) -> tuple[Path, Path, dict]:
    """A capture of mice left and right 270 mm apart (450 CPI) driven by ``moves``
    (build_motion's): the config with ``mounts``, the capture, the mice's reports."""
    mice = [
        SynthMouse("left", 0.0, 0.135, cpi_x=450, cpi_y=450),
        SynthMouse("right", 0.0, -0.135, cpi_x=450, cpi_y=450, phase=0.5),
    ]
    motion = build_motion(moves)
    rec = {m.name: mouse_reports(m, motion, i) for i, m in enumerate(mice)}
    cap = write_native(tmp_path / "turns.mdcap", rec)
    return write_config(tmp_path, mounts), cap, rec


def test_distance_json_and_write(tmp_path):
    eta = math.radians(90)
    pivot = (0.0, 0.03)
    moves = [(eta * pivot[1] * s, -eta * pivot[0] * s, eta * s, 2.0) for s in (1, -1, 1, -1)]
    cfg, cap, rec = _pair_drive(tmp_path, moves, {
        "left": {"cpi": 450, "mount": {"x": 0.01, "y": 0.125}},
        "right": {"cpi": 450, "mount": {"x": 0.01, "y": -0.125}},
        "rear": {"cpi": 450, "mount": {"x": -0.2, "y": 0}},
    })  # fmt: skip
    caps = ["--capture", f"left={cap}", "--capture", f"right={cap}"]
    p = ok(calib("distance", cfg, *caps, "--angle", "90", "--json"))
    doc = json.loads(p.stdout)
    assert set(doc) == {"distance", "stderr", "runs"} and doc["runs"] == 4
    assert doc["distance"] == pytest.approx(0.27, abs=5e-4)
    ok(calib("distance", cfg, *caps, "--angle", "90", "--write"))
    cal = yaml.safe_load((tmp_path / "rig.calib.yaml").read_text())
    assert cal["distance"]["mice"] == ["left", "right"]
    # Same midpoint (0.01, 0) and direction, 270 mm apart.
    assert cal["mice"]["left"]["mount"]["y"] == pytest.approx(0.135, abs=3e-4)
    assert cal["mice"]["right"]["mount"]["x"] == pytest.approx(0.01, abs=1e-9)
    rear = write_native(tmp_path / "rear.mdcap", {"rear": rec["left"]})
    three = ["--capture", f"left={cap}", "--capture", f"right={cap}", "--capture", f"rear={rear}"]
    fails(
        calib("distance", cfg, *three, "--angle", "90"),
        "exactly two mice",
        "--mice",
    )
    fails(
        calib("distance", cfg, *caps, "--angle", "0"),
        "between 0.1 and 36000 degrees",
    )
    # Regression: the angle in radians (1.5708 for 90 deg) gave D = 15.5 m and no word.
    p = ok(calib("distance", cfg, *caps, "--angle", "1.5708"))
    assert "warning: the distance 15470.1 mm is +5630% off the configured 270.0 mm" in p.stderr
    assert "is --angle right (in degrees)?" in p.stderr
    fails(
        calib("distance", cfg, *caps, "--angle", "90", "--mice", "left"),
        "give two mouse names",
    )


@pytest.mark.parametrize("at", [0, 2, 4])
def test_distance_says_a_push_among_the_turns_is_no_turn(tmp_path, at):
    """A straight push among the turns moves both mice alike: it was left out as a
    "bump" (|d1 - d2| near 0 is under a quarter of the median run's), so the error for a
    push never came; a run is a bump by how far the mice moved, and the push is named."""
    eta = math.radians(90)
    moves = [(0.0, 0.0, eta * s, 2.0) for s in (1, -1, 1, -1)]
    moves.insert(at, (0.3, 0.0, 0.0, 2.0))
    cfg, cap, _ = _pair_drive(tmp_path, moves, {
        "left": {"cpi": 450, "mount": {"x": 0.0, "y": 0.135}},
        "right": {"cpi": 450, "mount": {"x": 0.0, "y": -0.135}},
    })  # fmt: skip
    caps = ["--capture", f"left={cap}", "--capture", f"right={cap}"]
    p = fails(
        calib("distance", cfg, *caps, "--angle", "90"), f"run {at + 1}: both mice moved alike"
    )
    assert "bump" not in p.stderr
    fails(
        calib("distance", cfg, *caps, "--angle", "90", "--mice", "left,left"),
        "names one mouse twice",
    )


# --------------------------------------------------------------------------- mounts


MOUNTS_TRUE = {  # x, y, yaw, CPI
    "a": (0.1575, 0.0, 0.05, 1020),
    "b": (-0.07875, 0.1365, 0.0, 1000),
    "c": (-0.07875, -0.1365, 0.0, 1000),
}


def mounts_recording(motion) -> dict[str, Reports]:
    """The reports of the three mice of ``mounts_session`` during ``motion``."""
    mice = [
        SynthMouse(n, x, y, yaw=math.degrees(yaw), cpi_x=cpi, cpi_y=cpi, phase=0.2 * i)
        for i, (n, (x, y, yaw, cpi)) in enumerate(MOUNTS_TRUE.items())
    ]
    return {m.name: mouse_reports(m, motion, i) for i, m in enumerate(mice)}


@pytest.fixture
def mounts_session(tmp_path):
    """Three mice whose true mounts are 5 % off the nominal triangle (Kim & Lee's set-up),
    one with a yaw and a CPI error, and a body-twist reference."""
    motion = build_motion(
        [(0.3, 0, 0, 2), (0, 0, 1.5, 2), (0.2, 0, 0.8, 2), (0, 0.1, -1, 2), (-0.2, 0, 0, 2)]
    )
    nominal = {"a": (0.15, 0.0), "b": (-0.075, 0.13), "c": (-0.075, -0.13)}
    true = MOUNTS_TRUE
    rec = mounts_recording(motion)
    cap = write_native(tmp_path / "drive.mdcap", rec)
    ref = tmp_path / "REF.csv"
    ref.write_text(twist_csv(motion, 100.0))
    cfg = write_config(
        tmp_path, {n: {"cpi": 1000, "mount": {"x": x, "y": y}} for n, (x, y) in nominal.items()}
    )
    caps = [a for n in nominal for a in ("--capture", f"{n}={cap}")]
    return tmp_path, cfg, caps, ref, true, motion


def test_mounts_exact_json_and_write(mounts_session):
    tmp, cfg, caps, ref, true, _ = mounts_session
    p = ok(calib("mounts", cfg, *caps, "--reference", str(ref), "--json"))
    doc = json.loads(p.stdout)
    for n, (x, y, yaw, cpi) in true.items():
        # one scale: the CPIs are off alike on both axes (tests/test_calib_peraxis.py)
        assert set(doc[n]) == {"x", "y", "yaw", "scale", "scale_x", "scale_y"}
        assert doc[n]["scale_x"] == doc[n]["scale_y"] == doc[n]["scale"]
        assert doc[n]["x"] == pytest.approx(x, abs=1e-4)
        assert doc[n]["y"] == pytest.approx(y, abs=1e-4)
        assert doc[n]["yaw"] == pytest.approx(math.degrees(yaw), abs=0.05)
        assert doc[n]["scale"] == pytest.approx(cpi / 1000, rel=5e-4)
    ok(calib("mounts", cfg, *caps, "--reference", str(ref), "--write"))
    cal = yaml.safe_load((tmp / "rig.calib.yaml").read_text())
    assert cal["mice"]["a"]["cpi"]["x"] == pytest.approx(1020, rel=5e-4)
    assert cal["mice"]["a"]["mount"]["yaw"] == pytest.approx(math.degrees(0.05), abs=0.05)


def test_mounts_kimlee_side_by_side(mounts_session):
    tmp, cfg, caps, ref, true, _ = mounts_session
    p = ok(
        calib(
            "mounts",
            cfg,
            *caps,
            "--reference",
            str(ref),
            "--method",
            "kimlee",
            "--json",
        )
    )
    doc = json.loads(p.stdout)
    assert set(doc) == {"a", "b", "c"}
    assert doc["b"]["scale"] == 1.0 and doc["b"]["yaw"] == 0.0  # not estimated by Kim & Lee
    assert "Kim & Lee linearised" in p.stderr and "minimum-norm" in p.stderr
    exact = json.loads(
        ok(
            calib(
                "mounts",
                cfg,
                *caps,
                "--reference",
                str(ref),
                "--json",
            )
        ).stdout
    )

    def err(d):
        return max(math.hypot(d[n]["x"] - true[n][0], d[n]["y"] - true[n][1]) for n in true)

    assert err(exact) < 1e-4 < err(doc)


def test_mounts_wheel_reference(tmp_path):
    """A differential drive: wheel ticks through the McGill model are the reference."""
    r_wheel, track, tpr = 0.03, 0.25, 2048.0
    motion = build_motion([(0.4, 0, 0, 2), (0, 0, 2.0, 2), (0.3, 0, 1.0, 2)])
    mice = [SynthMouse("front", 0.12, 0.02), SynthMouse("rear", -0.1, -0.03, phase=0.5)]
    rec = {m.name: mouse_reports(m, motion, i) for i, m in enumerate(mice)}
    cap = write_native(tmp_path / "drive.mdcap", rec)
    t = np.linspace(0, motion.end, 2000)
    u = motion.integral(t)
    left = (u[:, 0] - u[:, 2] * track / 2) / r_wheel / (2 * math.pi) * tpr
    right = (u[:, 0] + u[:, 2] * track / 2) / r_wheel / (2 * math.pi) * tpr
    ref = tmp_path / "ticks.csv"
    ref.write_text(
        "t,left,right\n"
        + "".join(f"{a:.6f},{b:.3f},{c:.3f}\n" for a, b, c in zip(t, left, right, strict=True))
    )
    cfg = write_config(
        tmp_path,
        {"front": {"cpi": 1000, "mount": {"x": 0.1}}, "rear": {"cpi": 1000, "mount": {"x": -0.1}}},
    )
    caps = ["--capture", f"front={cap}", "--capture", f"rear={cap}"]
    fails(
        calib("mounts", cfg, *caps, "--reference", str(ref)),
        "needs the wheel geometry",
    )
    fails(
        calib(
            "mounts",
            cfg,
            *caps,
            "--reference",
            str(ref),
            "--track",
            "0.25",
        ),
        "go together",
    )
    p = ok(
        calib(
            "mounts",
            cfg,
            *caps,
            "--reference",
            str(ref),
            "--wheel-radius",
            "0.03",
            "--ticks-per-rev",
            "2048",
            "--track",
            "0.25",
            "--json",
        )
    )
    doc = json.loads(p.stdout)
    assert doc["front"]["x"] == pytest.approx(0.12, abs=2e-4)
    assert doc["rear"]["y"] == pytest.approx(-0.03, abs=2e-4)
    # The config's wheels: section serves as well.
    cfg2 = write_config(
        tmp_path,
        {"front": {"cpi": 1000, "mount": {"x": 0.1}}, "rear": {"cpi": 1000, "mount": {"x": -0.1}}},
        extra="wheels: {radius: 0.03, track: 0.25, ticks_per_rev: 2048}\n",
    )
    p = ok(
        run_mousedom(
            "calibrate", "mounts", "--config", str(cfg2), *caps, "--reference", str(ref), "--json"
        )
    )
    assert json.loads(p.stdout)["front"]["x"] == pytest.approx(0.12, abs=2e-4)


def test_mounts_bad_inputs(mounts_session):
    tmp, cfg, caps, ref, true, motion = mounts_session
    bad = tmp / "bad.csv"
    bad.write_text("time,vx,vy,omega\n0,0,0,0\n")
    fails(
        calib("mounts", cfg, *caps, "--reference", str(bad)),
        "bad.csv:1: header must be t,vx,vy,omega",
    )
    bad.write_text(twist_csv(motion).replace("\n1.", "\n1.x", 1))
    fails(
        calib("mounts", cfg, *caps, "--reference", str(bad)),
        "bad.csv:",
        ": t: not a number",
    )
    late = tmp / "late.csv"
    late.write_text(twist_csv(motion, t_offset=100.0))
    fails(
        calib("mounts", cfg, *caps, "--reference", str(late)),
        "share one time base",
    )
    # Kim & Lee's own experiment, a self-rotation: flagged, not solved.
    spin = build_motion([(0, 0, 2.0, 3), (0, 0, -2.0, 3)])
    mice = [SynthMouse(n, x, y) for n, (x, y, *_) in true.items()]
    rec = {m.name: mouse_reports(m, spin, i) for i, m in enumerate(mice)}
    cap = write_native(tmp / "spin.mdcap", rec)
    spin_ref = tmp / "spin.csv"
    spin_ref.write_text(twist_csv(spin))
    spin_caps = [a for n in true for a in ("--capture", f"{n}={cap}")]
    fails(
        calib("mounts", cfg, *spin_caps, "--reference", str(spin_ref)),
        "rotation about one point",
        "add a straight drive",
    )


# --------------------------------------------------------------------------- scales


def _scale_drive(tmp_path: Path, seconds: float, n_mice: int = 3, true_left: float = 1.05):
    """Evemu files of a simulated drive (straights, arcs, turns, pauses) of a triangle rig
    whose mouse 'left' really has ``true_left`` times the CPI its config says; the config
    (right's CPI from a calibration file already there).  Returns (config, --capture args,
    the true CPIs)."""
    import dataclasses

    from mousedom.fusion import sim

    rig = sim.three_mouse_rig(cpi=800.0, report_hz=250.0)
    mice = [dataclasses.replace(m, noise=0.3, stamp_delay=0.002) for m in rig.mice[:n_mice]]
    mice[-1] = dataclasses.replace(mice[-1], cpi_x=1200.0, cpi_y=1190.0)  # right, calibrated
    rig = dataclasses.replace(rig, mice=tuple(mice))
    true = dataclasses.replace(mice[1], cpi_x=800.0 * true_left, cpi_y=800.0 * true_left)
    faulty = dataclasses.replace(rig, mice=(mice[0], true, *mice[2:]))
    legs, k = [sim.straight(0.3 * min(seconds, 1.0), 0.3)], 0
    while 2.6 * (k + 1) < seconds:  # each round: about 2.6 s
        legs += [sim.straight(0.3, 0.3), sim.arc(0.4, math.pi / 4 * (-1) ** k, 0.3),
                 sim.turn(math.pi / 4, 0.8), sim.pause(0.3)]  # fmt: skip
        k += 1
    res = sim.simulate(faulty, sim.sequence(*legs), seed=7)
    text = sim.rig_yaml(rig, cpi={mice[-1].name: (1000.0, 1000.0)})  # before calibration
    cfg = write_config(tmp_path, {}, extra="")  # (the file is replaced just below)
    cfg.write_text(text + "calibration: rig.calib.yaml\n")
    (tmp_path / "rig.calib.yaml").write_text(
        f"mice:\n  {mice[-1].name}:\n    cpi: {{x: 1200.0, y: 1190.0}}\n"
        "    mount: {x: -0.075, y: -0.1299}\n"
    )
    caps = []
    for m in rig.mice:
        f = write_evemu(tmp_path / f"{m.name}.events", res.reports[m.name])
        caps += ["--capture", f"{m.name}={f}"]
    cpis = {m.name: (m.cpi_x, m.cpi_y) for m in faulty.mice}
    return cfg, caps, cpis


def test_scales_write_the_cpi_the_others_imply(tmp_path):
    """Issue 31 item 3: a drive on which one of three mice reads 5 % more than its CPI
    says; `calibrate scales` prints each mouse's scale, spread and implied CPI and --write
    stores the corrected CPI of that mouse (within 0.5 % of the truth) and leaves the
    others' as they were (a mouse already calibrated keeps its file entry)."""
    cfg, caps, true = _scale_drive(tmp_path, 12.0)
    out = ok(calib("scales", cfg, *caps))
    lines = out.stdout.splitlines()
    assert lines[0].startswith("calibrate scales: 3 mice")
    left = next(line for line in lines if line.startswith("left "))
    assert "5.0 % more" in left and float(left.split()[1]) == pytest.approx(1 / 1.05, rel=0.002)
    front = next(line for line in lines if line.startswith("front "))
    assert front.endswith("unchanged: within spread"), front
    assert "common to all the mice cannot be seen" in out.stdout
    assert not (tmp_path / "rig.calib.yaml").read_text().count("scales")  # no --write: as was
    wrote = ok(calib("scales", cfg, *caps, "--json", "--write"))
    doc = json.loads(wrote.stdout)
    # The triangle's drive never slides: the one scale is written to both axes, said so.
    assert "warning: left: cpi x and y both written 5.0% higher" in wrote.stderr
    assert "assumes both are off alike" in wrote.stderr
    assert doc["left"]["change"] is True and doc["left"]["implied_cpi"]["x"] == pytest.approx(
        840.0, rel=0.005
    )
    written = yaml.safe_load((tmp_path / "rig.calib.yaml").read_text())
    assert written["mice"]["left"]["cpi"]["x"] == pytest.approx(true["left"][0], rel=0.005)
    assert written["mice"]["left"]["cpi"]["y"] == pytest.approx(true["left"][1], rel=0.005)
    assert written["mice"]["right"] == {"cpi": {"x": 1200.0, "y": 1190.0},
                                        "mount": {"x": -0.075, "y": -0.1299}}  # fmt: skip
    assert "front" not in written["mice"]
    assert written["scales"]["left"]["cpi_before"] == {"x": 800.0, "y": 800.0}
    from mousedom.config import load_config

    config = load_config(str(cfg), need_sources=False)  # what the daemon will read
    for name, (cx, cy) in true.items():
        m = config.mouse(name)
        tol = 0.005 if name == "left" else 0.002
        assert (m.cpi_x, m.cpi_y) == pytest.approx((cx, cy), rel=tol), name
    # Again with the corrected CPI: every mouse agrees now, nothing is written.
    again = ok(calib("scales", cfg, *caps, "--write"))
    assert "not written: every mouse agrees with the others" in again.stderr
    assert "unchanged" in next(line for line in again.stdout.splitlines()
                               if line.startswith("left "))  # fmt: skip


def test_scales_refuse_two_mice_and_too_little_motion(tmp_path):
    """Two mice cannot tell which one is off; a second of driving, or scales known less
    well than --max-spread, is no calibration: exit 2, saying why, nothing written."""
    two = tmp_path / "two"
    two.mkdir()
    cfg, caps, _ = _scale_drive(two, 3.0, n_mice=2)
    fails(calib("scales", cfg, *caps, "--write"), "needs three or more mice (it has 2)")
    short = tmp_path / "short"
    short.mkdir()
    cfg, caps, _ = _scale_drive(short, 0.5)
    fails(calib("scales", cfg, *caps, "--write"),
          "too little motion to learn the scale of mouse front, left, right",
          "drive longer")  # fmt: skip
    fails(calib("scales", cfg, *caps, "--max-spread", "0"), "--max-spread: must be a percentage")
    some = tmp_path / "some"
    some.mkdir()
    cfg, caps, _ = _scale_drive(some, 5.0)
    fails(calib("scales", cfg, *caps, "--write", "--max-spread", "0.01"),
          "too little evidence: the scale is known only front to +- 0.0",
          "(--max-spread)")  # fmt: skip
    for d in (two, short, some):  # as _scale_drive wrote it
        assert "scales" not in yaml.safe_load((d / "rig.calib.yaml").read_text())


# --------------------------------------------------------------------------- ADNS captures


def write_adns_capture(path: Path, pushes: int, counts: int, drop: int | None = None) -> Path:
    """A native capture of a downsampler's raw bytes: pushes forth and back of ``counts``
    along the sensor's Delta_Y, 1 s each, 1 s pauses, one MOTION packet every 15 ms.
    ``drop``: leave out that packet (a sequence gap)."""
    from mousedom.sources import adns_protocol as P

    seq, t_us, host = 0, 0, 100.0
    ts, pieces = [], []
    for k in range(pushes):
        per = [counts // 66] * 66
        per[-1] += counts - sum(per)
        for moving in (True, False):
            for i in range(66):
                seq, t_us, host = seq + 1, t_us + 15000, host + 0.015
                dy = (-1) ** k * per[i] if moving else 0
                pk = P.Motion(seq, t_us, 0, dy, 12, 80, P.FLAG_RES1600)
                if seq != drop:
                    ts.append(host + 0.002)
                    pieces.append(P.encode_packet(pk))
    dev = DeviceInfo(name="downsampler", kind="serial", mouse="floor", rel_xy=True)
    with NativeWriter(path, [dev]) as w:
        w.serial_many(0, ts, pieces)
        w.sync(host + 1)
    return path


def test_cpi_from_an_adns_capture(tmp_path):
    """Regression: the serial bytes of a recorded downsampler were never decoded, so an
    ADNS mouse could not be calibrated from a capture ('found 0 run(s)')."""
    counts = 12598  # 0.2 m at 1600 cpi, to the count
    cap = write_adns_capture(tmp_path / "adns.mdcap", 6, counts)
    cfg = write_config(
        tmp_path,
        {"floor": {"cpi": 1500, "mount": {"x": 0.1}, "serial": {"port": "/dev/ttyUSB0"}}},
        extra="model: diff-drive\n",
    )
    base = ["calibrate", "cpi", "--config", str(cfg), "--distance", "0.2", "--json"]
    doc = json.loads(ok(run_mousedom(*base, "--capture", str(cap))).stdout)
    assert doc["floor"]["runs"] == 6
    assert doc["floor"]["cpi"] == pytest.approx(counts / (0.2 / 0.0254), abs=1e-3)
    # A packet lost on the line: its counts are missing, so no answer.
    lossy = write_adns_capture(tmp_path / "lossy.mdcap", 6, counts, drop=20)
    fails(
        run_mousedom(*base, "--capture", str(lossy)),
        "lossy.mdcap: device 'downsampler' (mouse floor): 1 serial packet(s) lost",
    )


# --------------------------------------------------------------------------- --write safety


def test_write_never_leaves_a_calibration_that_does_not_load(cpi_session):
    """Regression: --write replaced the file first and checked it after, so a result the
    config refuses (here cpi 0.0 from a --distance in the wrong unit) stayed on disk and
    broke the next daemon start or SIGHUP.  Now the old file is put back.  (Such a CPI is
    refused before the store too, as no mouse's: --force passes that, to reach the store.)"""
    tmp, cfg, files = cpi_session
    base = ["calibrate", "cpi", "--config", str(cfg), "--capture", f"left={files['left']}"]
    cal = tmp / "rig.calib.yaml"
    p = fails(run_mousedom(*base, "--distance", "1e6", "--write", "--force"), "not written")
    assert "mice.left.cpi.y: must be a positive number" in p.stderr
    assert not cal.exists()  # there was none before
    ok(run_mousedom(*base, "--distance", "0.2", "--write"))
    before = cal.read_bytes()
    fails(run_mousedom(*base, "--distance", "1e6", "--write", "--force"), "not written")
    assert cal.read_bytes() == before
    assert sorted(p.name for p in tmp.iterdir() if p.name.startswith(".")) == []
    ok(run_mousedom("check-config", "--config", str(cfg), "--no-sources"))


def test_distance_write_with_mice_at_one_point(tmp_path):
    """Regression: two mice configured at one point have no line to be spread along, and
    --write stored mount: {x: .nan, y: .nan}."""
    eta = math.radians(90)
    motion = build_motion([(0, 0, eta * s, 2.0) for s in (1, -1, 1)])
    mice = [SynthMouse("left", 0.0, 0.135), SynthMouse("right", 0.0, -0.135, phase=0.5)]
    cap = write_native(
        tmp_path / "turns.mdcap", {m.name: mouse_reports(m, motion, i) for i, m in enumerate(mice)}
    )
    cfg = write_config(
        tmp_path,
        {"left": {"cpi": 1000, "mount": {"x": 0.1}}, "right": {"cpi": 1000, "mount": {"x": 0.1}}},
        extra="model: diff-drive\n",
    )
    p = fails(
        calib("distance", cfg, "--capture", str(cap),
            "--angle", "90", "--write",
        ),
        "mice left and right sit at one point in the config",
    )  # fmt: skip
    assert "RuntimeWarning" not in p.stderr
    assert not (tmp_path / "rig.calib.yaml").exists()


def test_separate_relative_files_follow_one_rule_in_calibrate_and_replay(cpi_session):
    """Issue 11 item 7: replay fused separate relative-time files as if they shared t = 0
    without a word, and calibration refused the same files.  One rule now: they are
    aligned at their t = 0, and both commands say so in the same warning."""
    tmp, cfg, files = cpi_session
    rel = {}
    for name, path in files.items():
        lines = [ln.split(" ", 2) for ln in path.read_text().splitlines()]
        t0 = float(lines[0][1])
        rel[name] = tmp / f"{name}.rel.events"
        rel[name].write_text("".join(f"E: {float(t) - t0:.6f} {rest}\n" for _, t, rest in lines))
    caps = [f"--capture={n}={p}" for n, p in rel.items()]
    cal = ok(calib("cpi", cfg, "--distance", "0.2", "--axis", "y", "--json", *caps))
    rep = ok(run_mousedom("replay", "--config", str(cfg), *caps))
    for proc in (cal, rep):
        warned = [ln for ln in proc.stderr.splitlines() if "aligned at their t = 0" in ln]
        assert len(warned) == 1 and "left.rel.events, right.rel.events" in warned[0], proc.stderr
    result = json.loads(cal.stdout)
    assert result["left"]["cpi"] == pytest.approx(455, rel=3e-3)  # as with absolute times


def test_cpi_on_a_jig_needs_no_mount_and_no_solvable_model(tmp_path):
    """Issue 14 item 8: one mouse on a jig, no mount: calibrate cpi demanded a rig valid
    for fusion (lsq needs two mice).  It checks what it uses, and --write stores it."""
    motion = build_motion([(0.2 * (-1) ** k, 0, 0, 1.2) for k in range(6)])
    f = write_evemu(tmp_path / "m.events", mouse_reports(SynthMouse("m", 0, 0, cpi_y=812), motion))
    (tmp_path / "rig.yaml").write_text("calibration: rig.calib.yaml\nmice:\n  m: {cpi: 800}\n")
    p = ok(calib("cpi", tmp_path / "rig.yaml", "--capture", f"m={f}", "--distance", "0.2",
                 "--json", "--write"))  # fmt: skip
    assert json.loads(p.stdout)["m"]["cpi"] == pytest.approx(812, rel=3e-3)
    stored = yaml.safe_load((tmp_path / "rig.calib.yaml").read_text())
    assert stored["mice"]["m"]["cpi"]["y"] == pytest.approx(812, rel=3e-3)
    # the daemon, which fuses, still refuses this rig, and says why
    p = run_mousedom("check-config", "--config", str(tmp_path / "rig.yaml"), "--no-sources")
    assert p.returncode == 2 and "mount" in p.stderr


def test_distance_on_a_three_mouse_rig_says_which_mice_to_choose(tmp_path):
    mice = {
        n: {"cpi": 400, "mount": {"x": x, "y": 0}} for n, x in (("a", 0.1), ("b", 0), ("c", -0.1))
    }
    cfg = write_config(tmp_path, mice)
    motion = build_motion([(0.0, 0.0, math.radians(90) * s, 2.0) for s in (1, -1)])
    caps = []
    for i, (n, x) in enumerate((("a", 0.1), ("b", 0.0), ("c", -0.1))):
        f = write_evemu(tmp_path / f"{n}.events", mouse_reports(SynthMouse(n, x, 0.05), motion, i))
        caps += ["--capture", f"{n}={f}"]
    p = fails(calib("distance", cfg, "--angle", "90", *caps))
    assert "3 have data (a, b, c; the config has a, b, c): choose two with --mice A,B" in p.stderr


def write_native_interleaved(path: Path, recording: dict[str, Reports], chunk: float = 0.1) -> Path:
    """As ``write_native``, but in time order, ``chunk`` seconds of every mouse at a time, as
    the recorder writes: a file cut anywhere holds every mouse up to about one time."""
    devices = [DeviceInfo(name=f"sim {n}", mouse=n) for n in recording]
    end = max(float(r.t[-1]) for r in recording.values())
    with NativeWriter(path, devices, time_base="monotonic") as w:
        for a in np.arange(0.0, end + chunk, chunk):
            for i, rep in enumerate(recording.values()):
                sel = (rep.t >= a) & (rep.t < a + chunk)
                if sel.any():
                    w.motion(i, rep.t[sel], rep.dx[sel].astype(int), rep.dy[sel].astype(int))
            w.sync(min(a + chunk, end))
    return path


@pytest.mark.parametrize("cut", [1.7, 4.1, 7.5, 10.9, 13.0])
def test_mounts_refuse_a_capture_truncated_mid_motion(mounts_session, cut):
    """Regression: a capture cut short (here its bytes, in the middle of a chunk, as a full
    disk or a killed recorder leaves it) was fitted to the whole reference with exit 0, and
    --write stored mice at (0, 27 mm) with scale 2.23.  Refused now, with exit 2, and
    nothing is written.  ``cut``: a time in the hold of a move, where much motion is left."""
    tmp, cfg, caps, ref, _, motion = mounts_session
    rec = mounts_recording(motion)
    early = {
        n: Reports(n, r.t[r.t < cut], r.dx[r.t < cut], r.dy[r.t < cut]) for n, r in rec.items()
    }
    size = write_native_interleaved(tmp / "early.mdcap", early).stat().st_size
    cap = write_native_interleaved(tmp / "drive.mdcap", rec)
    cap.write_bytes(cap.read_bytes()[: size + 20])  # into the next chunk's header and data
    p = calib("mounts", cfg, *caps, "--reference", str(ref), "--write")
    fails(p, f"{ref}: the reference moves at", "the captures end in the middle of a motion")
    assert not (tmp / "rig.calib.yaml").exists()


@pytest.mark.parametrize("what", ["cpi", "mounts"])
def test_a_mouse_whose_own_capture_ends_in_a_run_is_named(mounts_session, what):
    """One mouse's evemu capture cut in the middle of the third run, the others whole: its
    part of that run would be taken for the whole run (a wrong CPI, wrong mounts)."""
    tmp, cfg, caps, ref, _, motion = mounts_session
    rec = mounts_recording(motion)
    args = []
    for n, rep in rec.items():
        keep = rep.t <= (7.5 if n == "b" else np.inf)
        part = Reports(n, rep.t[keep], rep.dx[keep], rep.dy[keep])
        args += ["--capture", f"{n}={write_evemu(tmp / f'{n}.events', part)}"]
    extra = ["--reference", str(ref)] if what == "mounts" else ["--distance", "0.3"]
    fails(calib(what, cfg, *args, *extra), "mouse b: its motion ends at t = ", "inside run 3")


@pytest.mark.parametrize("true_cpi", [5.45e8, 40.0, 40000.0])
def test_a_cpi_no_mouse_reports_is_not_stored_without_force(tmp_path, true_cpi):
    """Regression: a capture whose counts are hostile (near 2^31 a report) gave a CPI of
    545 million, stored by --write with only a warning, and check-config said nothing of
    it.  A result outside what mice report (``plausible.CPI_RANGE``) is now a warning that
    --write refuses (exit 2) unless --force; stored, check-config names its file and line.
    Past the config's own limits (CPI 1 to 1e6: no rig has more) not even --force stores
    it: the file written is read back and refused, and the old one stays."""
    motion = build_motion([(0.2 * (-1) ** k, 0, 0, 1.2) for k in range(4)])
    rep = mouse_reports(SynthMouse("m", 0, 0, cpi_x=true_cpi, cpi_y=true_cpi), motion, 0)
    cap = write_evemu(tmp_path / "m.events", rep)
    mice = {"m": {"cpi": 1000, "mount": {"x": 0, "y": 0.1}}, "n": {"cpi": 1000, "mount": {"x": 0}}}
    cfg = write_config(tmp_path, mice)
    args = ["--capture", f"m={cap}", "--mouse", "m", "--distance", "0.2"]
    p = ok(calib("cpi", cfg, *args))
    assert "counts per inch is outside" in p.stderr
    fails(calib("cpi", cfg, *args, "--write"), "not written", "--force")
    assert not (tmp_path / "rig.calib.yaml").exists()
    if true_cpi > 1e6:
        fails(calib("cpi", cfg, *args, "--write", "--force"), "the result does not load",
              "mice.m.cpi.y: must be between 1 and 1e+06")  # fmt: skip
        assert not (tmp_path / "rig.calib.yaml").exists()
        return
    ok(calib("cpi", cfg, *args, "--write", "--force"))
    p = ok(run_mousedom("check-config", "--config", str(cfg), "--no-sources"))
    assert re.search(r"rig\.calib\.yaml:\d+: .*counts per inch is outside", p.stderr), p.stderr


def test_mounts_scale_to_a_cpi_no_mouse_reports_is_not_stored(mounts_session):
    """An exact fit's scale that turns the CPI into one no mouse reports (here a capture
    whose mouse a reports 100 times its counts) is refused by --write unless --force."""
    tmp, cfg, caps, ref, _, motion = mounts_session
    rec = mounts_recording(motion)
    a = rec["a"]
    rec["a"] = Reports("a", a.t, a.dx * 100, a.dy * 100)  # 102,000 CPI: scale 102
    write_native(tmp / "drive.mdcap", rec)
    args = [*caps, "--reference", str(ref), "--window", "0"]
    fails(
        calib("mounts", cfg, *args, "--write"),
        "mouse a: scale 10",
        "counts per inch is outside",
        "not written",
    )
    assert not (tmp / "rig.calib.yaml").exists()
    ok(calib("mounts", cfg, *args, "--write", "--force"))


def test_mounts_say_a_mouse_whose_flip_is_wrong_and_store_nothing(mounts_session):
    """Mouse b read through a mirror (its REL_X negated: a flip the config does not say)
    was fitted 0.1 m and its CPI 60 % off, and --write stored that with exit 0."""
    tmp, cfg, caps, ref, _, motion = mounts_session
    rec = mounts_recording(motion)
    b = rec["b"]
    rec["b"] = Reports("b", b.t, -b.dx, b.dy)
    write_native(tmp / "drive.mdcap", rec)
    for extra in ((), ("--write", "--force")):
        fails(
            calib("mounts", cfg, *caps, "--reference", str(ref), *extra),
            "mouse b: its readings are a mirror image",
            "`flip` for it is wrong (it says flip: false)",
        )
    assert not (tmp / "rig.calib.yaml").exists()


def test_scales_on_captures_without_motion_say_one_error(tmp_path):
    """Regression: replay's "no motion reports in the captures: no pose to write" came
    before scales' own error: two lines for one problem.  Now one error, exit 2."""
    cfg, _, cpis = _scale_drive(tmp_path, 0.5)
    cap = tmp_path / "still.mdcap"
    devices = [DeviceInfo(name=f"sim {n}", mouse=n) for n in cpis]
    with NativeWriter(cap, devices, time_base="monotonic") as w:
        w.sync(5.0)
    caps = [a for n in cpis for a in ("--capture", f"{n}={cap}")]
    p = fails(calib("scales", cfg, *caps), "the captures hold no motion")
    assert len(p.stderr.splitlines()) == 1, p.stderr


def test_a_reference_in_other_units_is_hinted_at_in_the_mounts_error():
    """REF.csv is in s, m/s and rad/s.  omega in degrees per second fitted a mouse 150 mm
    ahead at 2.6 mm with a residual of 7 um and exit 0 (or read as "all the motion is a
    rotation about one point"), t in milliseconds as "no motion at all": refused now,
    saying which column looks off."""
    import numpy as np

    from mousedom.calibrate.reference import Reference
    from mousedom.calibrate.session import _units_hint, make_session
    from mousedom.config import parse_config
    from mousedom.sources.base import Reports

    cfg = parse_config("mice:\n  a: {cpi: 800, mount: {x: 0.1, y: 0}}\nmodel: diff-drive\n",
                       need_sources=False)  # fmt: skip
    t = np.arange(0.0, 20.0, 0.01)
    session = make_session(cfg, {"a": Reports("a", t, np.ones_like(t), np.ones_like(t))}, [])
    twist = np.zeros((len(t), 3))
    twist[:, 2] = 1.5
    assert _units_hint(Reference("twist", t, twist, "r.csv"), session) == ""
    degs = twist * 57.3
    assert "omega reaches 85.95 rad/s: degrees per second?" in _units_hint(
        Reference("twist", t, degs, "r.csv"), session)  # fmt: skip
    assert "t spans 19990 s where the capture spans 20 s: milliseconds?" in _units_hint(
        Reference("twist", t * 1000, twist, "r.csv"), session)  # fmt: skip
    assert "m/s: millimetres per second?" in _units_hint(
        Reference("twist", t, np.array([[300.0, 0.0, 0.0]] * len(t)), "r.csv"), session
    )


@pytest.mark.parametrize("seed", range(4))
def test_a_reference_sample_far_out_is_named_by_its_time(mounts_session, seed):
    """A single REF.csv sample far out (a logger's glitch, hostile data: 1e3-1e11 in any
    column, in a pause or in a run) is refused naming the column and the sample's time.
    In a pause it was refused as "the reference moves ... where every mouse was still
    (100055540043% of a run's motion) ... the captures begin in the middle of a motion",
    naming neither."""
    tmp, cfg, caps, ref, _, motion = mounts_session
    rng = np.random.default_rng(seed)
    lines = ref.read_text().splitlines()
    column = int(rng.integers(1, 4))
    for row in rng.choice(np.arange(1, len(lines)), 3, replace=False):
        bad = lines.copy()
        fields = bad[row].split(",")
        fields[column] = f"{rng.choice([-1, 1]) * 10.0 ** rng.uniform(3, 11):.6g}"
        bad[row] = ",".join(fields)
        (tmp / "bad.csv").write_text("\n".join(bad) + "\n")
        p = fails(calib("mounts", cfg, *caps, "--reference", str(tmp / "bad.csv")))
        name = "omega reaches" if column == 3 else "vx, vy reach"
        assert name in p.stderr and f"(at t = {float(fields[0]):.3f} s)" in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1
