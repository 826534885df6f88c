"""Writers never follow a link, never clobber an input, and say which (issue 11, item 4).

Unit tests of mousedom.safewrite, then the commands that once followed links or
overwrote their own config, run as real processes."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import numpy as np
import pytest
from capture_helpers import PS2, external_dir, one_mouse_config
from conftest import run_mousedom
from test_replay_errors import _one_error_line

from mousedom.capture.evemu import format_evemu
from mousedom.errors import UserError
from mousedom.safewrite import open_stream, replace_bytes, replace_file


def test_stream_through_a_link_to_a_file_is_refused_and_the_target_kept(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("keep me")
    link = tmp_path / "out.csv"
    link.symlink_to(target)
    with pytest.raises(UserError, match="symbolic link"):
        open_stream(str(link))
    assert target.read_text() == "keep me"


def test_stream_through_a_dangling_link_creates_nothing(tmp_path):
    link = tmp_path / "out.mdcap"
    link.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(UserError, match="symbolic link"):
        open_stream(str(link))
    assert not (tmp_path / "elsewhere").exists()


def test_stream_onto_an_input_by_another_name_is_refused_before_truncation(tmp_path):
    config = tmp_path / "rig.yaml"
    config.write_text("rate_hz: 100\n")
    hard = tmp_path / "hard.yaml"
    os.link(config, hard)
    for out in (config, hard):
        with pytest.raises(UserError, match="is the input"):
            open_stream(str(out), [str(config)])
    assert config.read_text() == "rate_hz: 100\n"


def test_stream_to_a_new_file_an_old_file_and_a_device(tmp_path):
    new = tmp_path / "new.csv"
    with open_stream(str(new), text=True) as f:
        f.write("a\n")
    with open_stream(str(new), text=True) as f:  # an old output is truncated
        f.write("b\n")
    assert new.read_text() == "b\n"
    with open_stream(str(new), append=True, text=True) as f:
        f.write("c\n")
    assert new.read_text() == "b\nc\n"
    with open_stream("/dev/null") as f:  # a device is written as it is
        f.write(b"x")


def test_whole_file_replaces_atomically_and_refuses_links_and_inputs(tmp_path):
    out = tmp_path / "cal.yaml"
    out.write_text("old")
    out.chmod(0o640)
    replace_bytes(str(out), b"new")
    assert out.read_text() == "new" and stat.S_IMODE(out.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]  # no temporary left

    def broken(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(UserError, match="No space left"):
        replace_file(str(out), broken)
    assert out.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]

    link = tmp_path / "link.yaml"
    link.symlink_to(out)
    with pytest.raises(UserError, match="symbolic link"):
        replace_bytes(str(link), b"x")
    with pytest.raises(UserError, match="is the input"):
        replace_bytes(str(out), b"x", [str(out)])
    assert out.read_text() == "new" and link.is_symlink()


def _rig(tmp_path):
    return one_mouse_config(tmp_path, rate=1000)


def test_replay_outputs_refuse_links(tmp_path):
    """--plot and --umbmark-csv are written after the replay: a 2 s capture, not the PS/2
    recording (minutes of it at 1000 Hz, 18 s of the three runs), reaches them as surely."""
    cfg = _rig(tmp_path)
    target = tmp_path / "victim"
    target.write_text("keep")
    n = 250
    short = tmp_path / "short.evemu"
    short.write_text(format_evemu(np.arange(1, n + 1) * 0.008, np.full(n, 3), np.full(n, -2)))
    cap = f"m={short}"
    for flag, name in (("-o", "out.csv"), ("--plot", "out.png"), ("--umbmark-csv", "runs.csv")):
        link = tmp_path / name
        link.symlink_to(target)
        extra = ["--umbmark", "cw", "--true-end", "0,0"] if flag == "--umbmark-csv" else []
        proc = run_mousedom(
            "replay", "--config", str(cfg), "--capture", cap, flag, str(link), *extra
        )
        assert proc.returncode != 0, (flag, proc.stderr)
        _one_error_line(proc.stderr, str(link), "symbolic link")
        assert target.read_text() == "keep"
        link.unlink()


def test_convert_refuses_a_link_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "victim"
    target.write_text("keep")
    link = tmp_path / "out.mdcap"
    link.symlink_to(target)
    proc = run_mousedom("convert", "--capture", f"m={external_dir() / PS2}", "-o", str(link))
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "symbolic link")
    assert target.read_text() == "keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mdcap", "victim"]


def test_run_record_onto_the_running_config_is_refused(tmp_path):
    """`run --record rig.yaml` overwrote the running config; now it stops with one line
    before anything is written."""
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "rate_hz: 50\nmodel: diff-drive\nmice:\n  m:\n    cpi: 400\n"
        "    mount: {x: 0.1, y: 0.0, yaw: 0}\n"
        f"    replay: {{file: {external_dir() / PS2}}}\n"
    )
    before = cfg.read_bytes()
    proc = subprocess.run(
        [sys.executable, "-m", "mousedom", "run", "--config", str(cfg), "--record", str(cfg),
         "--socket", str(tmp_path / "s.sock")],
        capture_output=True, text=True, timeout=30, env={**os.environ, "PYTHONPATH": os.getcwd()},
    )  # fmt: skip
    assert proc.returncode != 0
    assert "is the input" in proc.stderr and "Traceback" not in proc.stderr
    assert cfg.read_bytes() == before


def _rig_with_inputs(tmp_path):
    """A rig whose config names a calibration file, an old evemu pair (.events + .desc)
    given on the command line, and a second capture named only by the config's replay:."""
    for ext in ("events", "desc"):
        (tmp_path / f"ps2.{ext}").write_bytes((external_dir() / f"{PS2[:-7]}.{ext}").read_bytes())
    (tmp_path / "other.events").write_bytes((external_dir() / PS2).read_bytes())
    (tmp_path / "rig.calib.yaml").write_text("mice:\n  m: {cpi: 812}\n")
    rig = ("rate_hz: 100\nmodel: diff-drive\ncalibration: rig.calib.yaml\nmice:\n"
           "  m: {cpi: 800, mount: {x: 0.1, y: 0.0, yaw: 0}, report_hz: 125}\n")  # fmt: skip
    (tmp_path / "rig.yaml").write_text(rig)
    (tmp_path / "rigr.yaml").write_text(rig.replace("125}", "125, replay: other.events}"))
    return {p.name: p.read_bytes() for p in tmp_path.iterdir()}


UMBMARK = ("--umbmark", "cw", "--true-end", "0,0")


@pytest.mark.parametrize(
    ("command", "target"),
    [
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", "-o"), "rig.calib.yaml"),
        (("convert", "-c", "rig.yaml", "--capture", "m=ps2.events", "-o"), "rig.calib.yaml"),
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", "--plot"), "rig.calib.yaml"),
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", *UMBMARK, "--umbmark-csv"),
         "rig.calib.yaml"),
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", *UMBMARK, "--umbmark-csv"),
         "ps2.desc"),
        (("replay", "-c", "rigr.yaml", *UMBMARK, "--umbmark-csv"), "other.events"),
        (("replay", "-c", "rigr.yaml", "-o"), "other.events"),
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", "-o", "x.csv", "--plot"),
         "x.csv"),
        (("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", *UMBMARK, "-o", "x.csv",
          "--umbmark-csv"), "x.csv"),
    ],
    ids=["replay-o-calibration", "convert-o-calibration", "plot-calibration",
         "umbmark-csv-calibration", "umbmark-csv-desc", "umbmark-csv-config-replay",
         "replay-o-config-replay", "two-outputs-one-file", "csv-and-umbmark-one-file"],
)  # fmt: skip
def test_no_output_names_an_input_or_another_output(tmp_path, command, target):
    """Every file a run reads (the config, its calibration, a capture, an evemu pair's
    .desc, a capture named by the config's replay:) is refused as any output's path, and
    so is one file for two outputs: one line naming it, a non-zero exit, every file as it
    was (found by a sweep: the calibration and these captures were overwritten)."""
    before = _rig_with_inputs(tmp_path)
    proc = run_mousedom(*command, target, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    _one_error_line(proc.stderr, target)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_two_outputs_may_share_a_device(tmp_path):
    """/dev/null takes the CSV and the UMBmark row alike (a run kept for its exit code)."""
    _rig_with_inputs(tmp_path)
    proc = run_mousedom("replay", "-c", "rig.yaml", "--capture", "m=ps2.events", *UMBMARK,
                        "-o", os.devnull, "--umbmark-csv", os.devnull, cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("target", ["rig.calib.yaml", "other.events", "ps2.desc"])
def test_run_record_onto_a_file_the_config_reads_is_refused(tmp_path, target):
    """`run --record` onto the config's calibration, the capture its replay: names or that
    capture's .desc: one line, a non-zero exit, before anything is written."""
    _rig_with_inputs(tmp_path)
    (tmp_path / "ps2.events").unlink()  # the .desc's pair is now other.events'
    (tmp_path / "ps2.desc").rename(tmp_path / "other.desc")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    target = "other.desc" if target == "ps2.desc" else target
    proc = subprocess.run(
        [sys.executable, "-m", "mousedom", "run", "--config", "rigr.yaml", "--record", target,
         "--socket", str(tmp_path / "s.sock")],
        capture_output=True, text=True, timeout=30, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": os.getcwd()},
    )  # fmt: skip
    assert proc.returncode != 0
    assert "is the input" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_run_refuses_one_file_for_its_two_recordings(tmp_path):
    """`run --record F --record-mcap F`: each writer would overwrite the other's file (the
    native capture lost, its closing line still logged); refused before anything opens."""
    _rig_with_inputs(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "mousedom", "run", "--config", "rigr.yaml", "--record", "out.x",
         "--record-mcap", "out.x", "--socket", str(tmp_path / "s.sock")],
        capture_output=True, text=True, timeout=30, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": os.getcwd()},
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "--record writes that file too" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out.x").exists()


@pytest.mark.parametrize("command", ["cpi", "scales"])
def test_calibrate_write_refuses_a_calibration_file_it_reads(tmp_path, command):
    """`calibrate ... --write` whose config names as its calibration file the capture it
    reads (a libinput record, which loads as YAML) rewrote the capture as calibration
    YAML, exit 0: refused before any work, with one line, the capture unchanged."""
    import numpy as np

    from mousedom.capture.libinput import format_libinput

    t = np.arange(1, 400) * 0.008
    steps = np.where((t // 1.0) % 2 == 0, 5, -5).astype(np.int64)
    (tmp_path / "push.yml").write_text(format_libinput([("m", t, steps, 0 * steps)]))
    (tmp_path / "rig.yaml").write_text(
        "rate_hz: 100\nmodel: diff-drive\ncalibration: push.yml\nmice:\n"
        "  m: {cpi: 800, mount: {x: 0.1, y: 0.0, yaw: 0}, report_hz: 125}\n"
    )
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    extra = ["--distance", "0.2"] if command == "cpi" else []
    proc = run_mousedom("calibrate", command, "--config", "rig.yaml", "--capture",
                        "m=push.yml", *extra, "--write", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    _one_error_line(proc.stderr, "push.yml", "not overwriting")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
