"""``mousedom replay`` / ``convert`` on outputs that fail and inputs that are wrong: one
clear line and a non-zero exit, never a traceback (real processes)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest
from capture_helpers import PS2, external_dir, one_mouse_config, replay_ps2
from conftest import mousedom_env, run_mousedom

needs_dev_full = pytest.mark.skipif(
    not os.path.exists("/dev/full") and not os.environ.get("CI"), reason="no /dev/full"
)


def _one_error_line(stderr: str, *needles: str) -> str:
    assert "Traceback" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mousedom: error:"), stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@needs_dev_full
def test_replay_csv_to_a_full_disk_is_one_line(tmp_path):
    cfg = one_mouse_config(tmp_path, rate=1000)
    proc = replay_ps2(cfg, "-o", "/dev/full")
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "/dev/full", "cannot write")


@needs_dev_full
@pytest.mark.parametrize("extra", [("-o", "-"), ()], ids=["csv", "summary"])
def test_replay_stdout_on_a_full_disk_is_one_line(tmp_path, extra):
    cfg = one_mouse_config(tmp_path, rate=1000)
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [sys.executable, "-m", "mousedom", "replay", "--config", str(cfg)]
            + ["--capture", f"m={external_dir() / PS2}", *extra],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            env=mousedom_env(),
            timeout=120,
        )
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "<stdout>", "cannot write")


@needs_dev_full
def test_convert_to_a_full_disk_or_missing_folder_is_one_line(tmp_path):
    src = f"m={external_dir() / PS2}"
    for out in ("/dev/full", str(tmp_path / "no" / "such" / "x.mdcap")):
        proc = run_mousedom("convert", "--capture", src, "-o", out)
        assert proc.returncode != 0
        _one_error_line(proc.stderr, out, "cannot write")


def test_convert_that_fails_half_way_leaves_no_short_capture(tmp_path):
    """A bad line deep in the input: no output file (it would replay as a short run
    without a word), and an older output of the same name is kept."""
    lines = (external_dir() / PS2).read_text().splitlines()
    at = len(lines) // 2
    lines.insert(at, "garbage")
    bad = tmp_path / "bad.events"
    bad.write_text("\n".join(lines) + "\n")
    (tmp_path / "bad.desc").write_bytes((external_dir() / PS2).with_suffix(".desc").read_bytes())
    out = tmp_path / "out.mdcap"
    proc = run_mousedom("convert", "--capture", f"m={bad}", "-o", str(out))
    assert proc.returncode != 0
    _one_error_line(proc.stderr, f"bad.events:{at + 1}:")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.desc", "bad.events"]
    out.write_bytes(b"older")
    proc = run_mousedom("convert", "--capture", f"m={bad}", "-o", str(out))
    assert proc.returncode != 0 and out.read_bytes() == b"older"


TWO_MICE = """\
rate_hz: 20
model: lsq
mice:
  a: {cpi: 800, mount: {x: 0.10, y: 0.05, yaw: 0}}
  b: {cpi: 800, mount: {x: -0.10, y: -0.05, yaw: 0}}
"""


def test_one_file_for_two_mice_feeds_both(tmp_path):
    """--capture a=F --capture b=F is the same as giving b a copy of F (both mice got
    the file's counts in the summary, but the fusion fed only one of them: exit 1)."""
    cfg = tmp_path / "two.yaml"
    cfg.write_text(TWO_MICE)
    src = external_dir() / "evemu-devices__Ultrathin_Touch_Mouse.events"
    copy = tmp_path / "copy.events"
    copy.write_bytes(src.read_bytes())
    same, copied = tmp_path / "same.csv", tmp_path / "copied.csv"
    for b, out in ((src, same), (copy, copied)):
        proc = run_mousedom(
            "replay", "--config", str(cfg), "--capture", f"a={src}", "--capture", f"b={b}",
            "-o", str(out),
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
    assert same.read_text() == copied.read_text()
    # Two identical mice moving together never turn: theta stays 0 to the last row.
    last = same.read_text().splitlines()[-1].split(",")
    assert float(last[3]) == 0.0 and float(last[1]) != 0.0

    from mousedom.capture import read_reports
    from mousedom.config import load_config

    reports, stats, _ = read_reports(load_config(str(cfg), need_sources=False),
                                     [("a", str(src)), ("b", str(src))])  # fmt: skip
    assert reports["a"].dx.sum() == reports["b"].dx.sum() == -319
    assert len(reports["a"].t) == len(reports["b"].t) == 349


def test_convert_refuses_two_devices_for_one_mouse(tmp_path):
    """The same multi-device file twice (or two files named for one mouse) made a capture
    that `replay` then refused ("mouse given twice"): refuse it when converting."""
    ext = external_dir()
    a, b = ext / PS2, ext / "evemu-devices__Saitek_Cyborg_RAT5_Mouse.events"
    two = tmp_path / "two.mdcap"
    proc = run_mousedom("convert", "--capture", f"x={a}", "--capture", f"y={b}", "-o", str(two))
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "out.mdcap"
    for caps in ((f"m={a}", f"m={b}"), (str(two), str(two))):
        args = [w for c in caps for w in ("--capture", c)]
        proc = run_mousedom("convert", *args, "-o", str(out))
        assert proc.returncode != 0
        _one_error_line(proc.stderr, "recorded twice")
        assert not out.exists()


def test_convert_refuses_one_file_given_twice_for_no_two_mice(tmp_path):
    """``convert --capture a.evemu --capture a.evemu`` wrote every report twice (replay
    refused the result only later): the same file by inode (another name, a link, the
    other half of an evemu pair) is refused unless each time names a different mouse."""
    ext = external_dir()
    src = ext / PS2
    a = tmp_path / "a.events"
    a.write_bytes(src.read_bytes())
    (tmp_path / "a.desc").write_bytes(src.with_suffix(".desc").read_bytes())
    link = tmp_path / "link.events"
    link.symlink_to(a)
    out = tmp_path / "out.mdcap"
    for caps in ((a, a), (a, link), (a, tmp_path / "a.desc"), (f"m={a}", a), (a, f"m={link}")):
        args = [w for c in caps for w in ("--capture", str(c))]
        proc = run_mousedom("convert", *args, "-o", str(out))
        assert proc.returncode == 2, (caps, proc.stderr)
        _one_error_line(proc.stderr, "the same file as --capture", "written twice")
        assert not out.exists()
    proc = run_mousedom("convert", "--capture", f"x={a}", "--capture", f"y={link}", "-o", str(out))
    assert proc.returncode == 0, proc.stderr  # two mice from one recording, as in replay
    assert "2 devices" in proc.stderr


def test_identical_mice_in_one_libinput_file_are_told_apart_by_node(tmp_path):
    """Two mice of one model share their name; libinput record keeps no phys/uniq, so
    such a recording could not be replayed at all.  replay.device matches the node."""
    import numpy as np

    from mousedom.capture.libinput import format_libinput

    t = np.arange(1, 51) * 0.01
    d = np.ones(50, dtype=int)
    rec = tmp_path / "same.yml"
    rec.write_text(
        format_libinput([("Logitech USB Optical Mouse", t, 3 * d, -d),
                         ("Logitech USB Optical Mouse", t + 0.002, 6 * d, -d)])
    )  # fmt: skip
    nodes = [ln.split()[-1] for ln in rec.read_text().splitlines() if ln.startswith("- node:")]
    assert len(set(nodes)) == 2
    cfg = tmp_path / "r.yaml"
    src = "replay: {{file: same.yml, device: {}}}"
    cfg.write_text(
        "rate_hz: 20\nmodel: lsq\nmice:\n"
        f"  a: {{cpi: 800, mount: {{x: 0.1, y: 0.05}}, {src.format(nodes[1])}}}\n"
        f"  b: {{cpi: 800, mount: {{x: -0.1, y: -0.05}}, {src.format(nodes[0])}}}\n"
    )
    proc = run_mousedom("replay", "--config", str(cfg))
    assert proc.returncode == 0, proc.stderr
    rows = {ln.split()[0]: ln.split() for ln in proc.stdout.splitlines() if ln[:2] in ("a ", "b ")}
    assert rows["a"][3] == "300" and rows["b"][3] == "150"
    # Without it, the message names the nodes to choose from.
    plain = tmp_path / "plain.yaml"
    plain.write_text(TWO_MICE)
    proc = run_mousedom("replay", "--config", str(plain), "--capture", f"a={rec}",
                        "--capture", f"b={rec}")  # fmt: skip
    assert proc.returncode != 0
    _one_error_line(proc.stderr, nodes[0], nodes[1], "replay.device")


@pytest.mark.parametrize("command", ["replay", "convert"])
def test_output_naming_an_input_is_refused_and_the_input_kept(tmp_path, command):
    """replay -o RUN.events truncated the recording before reading it (exit 0, data gone);
    convert compared paths only, so a .desc companion, the config or a link slipped by."""
    ext = external_dir()
    for suffix in (".events", ".desc"):
        (tmp_path / f"ps2{suffix}").write_bytes((ext / PS2).with_suffix(suffix).read_bytes())
    (tmp_path / "link.events").symlink_to(tmp_path / "ps2.events")
    cfg = one_mouse_config(tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    src = f"m={tmp_path / 'ps2.events'}"
    targets = ["ps2.events", "ps2.desc", "link.events", cfg.name]
    flags = [("-o",)] if command == "convert" else [("-o",), ("--plot",)]
    for target in targets:
        for (flag,) in flags:
            proc = run_mousedom(
                command, "--config", str(cfg), "--capture", src, flag, str(tmp_path / target)
            )
            assert proc.returncode != 0, (target, flag)
            _one_error_line(proc.stderr, target)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_pipe_as_capture_is_refused_before_reading(tmp_path):
    """`cat run.events | mousedom replay --capture m=/dev/stdin`: the format sniffing ate
    the first 64 kB, and the reader then complained about 'line 1' of the rest."""
    fifo = tmp_path / "pipe.events"
    os.mkfifo(fifo)
    cfg = one_mouse_config(tmp_path)
    for cmd in (("replay", "--config", str(cfg)), ("convert", "-o", str(tmp_path / "o.mdcap"))):
        proc = run_mousedom(*cmd, "--capture", f"m={fifo}", timeout=20)
        assert proc.returncode != 0
        _one_error_line(proc.stderr, "pipe.events", "not a regular file")


@pytest.mark.parametrize(
    "model, why",
    [("lsq", "needs at least two mice"), ("bonarini", "takes exactly two mice")],
)
def test_model_override_the_rig_cannot_support_is_refused(tmp_path, model, why):
    """--model skipped the config's own check: lsq on one mouse solved no window and
    ended at (0, 0, 0) with exit 0; bonarini was a ValueError traceback."""
    cfg = one_mouse_config(tmp_path)
    proc = replay_ps2(cfg, "--model", model)
    assert proc.returncode != 0
    _one_error_line(proc.stderr, f"--model {model}", why, "one.yaml")


def test_umbmark_row_never_lands_in_the_pose_csv_on_stdout(tmp_path):
    """`--umbmark ccw -o -` printed the RUNS.csv row after the poses: the CSV's last row
    was no longer the final pose."""
    from mousedom.demo import DEMO_CONFIG

    proc = run_mousedom("replay", "--config", str(DEMO_CONFIG), "--umbmark", "ccw", "-o", "-")
    assert proc.returncode != 0 and proc.stdout == ""
    _one_error_line(proc.stderr, "--umbmark-csv")
    runs = tmp_path / "runs.csv"
    proc = run_mousedom(
        "replay", "--config", str(DEMO_CONFIG), "--umbmark", "ccw", "-o", "-",
        "--umbmark-csv", str(runs),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    header, *_, last = (ln.split(",") for ln in proc.stdout.splitlines())
    assert len(last) == len(header) and last[header.index("ok")] == "1"
    assert runs.read_text().splitlines()[-1].startswith("ccw,")


def test_mixing_monotonic_and_relative_captures_warns(tmp_path):
    """A `mousedom record` file (seconds since boot) with a relative evemu file: no
    warning was given, and the replay ran through hours of empty windows between them."""
    import numpy as np

    from mousedom.capture import DeviceInfo, NativeWriter
    from mousedom.capture.evemu import format_evemu

    t = np.arange(1, 21) * 0.01
    d = np.ones(20, dtype=int)
    mono = tmp_path / "a.mdcap"
    with NativeWriter(mono, [DeviceInfo(name="a", mouse="a", rel_xy=True)]) as w:
        w.motion(0, 50.0 + t, d, -d)  # 50 s after boot
    rel = tmp_path / "b.evemu"
    rel.write_text(format_evemu(t, d, -d))
    cfg = tmp_path / "two.yaml"
    cfg.write_text(TWO_MICE)
    proc = run_mousedom(
        "replay", "--config", str(cfg), "--capture", str(mono), "--capture", f"b={rel}",
        "-o", str(tmp_path / "o.csv"),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "monotonic" in proc.stderr and "cannot be aligned" in proc.stderr
    assert "a.mdcap (monotonic)" in proc.stderr and "b.evemu (relative)" in proc.stderr


def test_convert_to_stdout_like_replay(tmp_path):
    """`convert -o -` made a file called '-'; replay's -o - is stdout, so is convert's now
    (the summary line goes to stderr, so the bytes on stdout are the capture alone)."""
    src = f"m={external_dir() / PS2}"
    proc = subprocess.run(
        [sys.executable, "-m", "mousedom", "convert", "--capture", src, "-o", "-"],
        capture_output=True, env=mousedom_env(), cwd=tmp_path, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "-").exists()
    assert b"2707 reports" in proc.stderr
    piped = tmp_path / "piped.mdcap"
    piped.write_bytes(proc.stdout)
    filed = tmp_path / "filed.mdcap"
    assert run_mousedom("convert", "--capture", src, "-o", str(filed)).returncode == 0
    cfg = one_mouse_config(tmp_path)
    a, b = (run_mousedom("replay", "--config", str(cfg), "--capture", str(p), "-o", "-")
            for p in (piped, filed))  # fmt: skip
    assert a.returncode == b.returncode == 0 and a.stdout == b.stdout and len(a.stdout) > 1000
    if os.path.exists("/dev/full"):
        with open("/dev/full", "wb") as full:
            proc = subprocess.run(
                [sys.executable, "-m", "mousedom", "convert", "--capture", src, "-o", "-"],
                stdout=full, stderr=subprocess.PIPE, text=True, env=mousedom_env(), timeout=120,
            )  # fmt: skip
        assert proc.returncode != 0
        _one_error_line(proc.stderr, "<stdout>", "cannot write")


def test_time_base_warning_comes_before_the_replay_not_after(tmp_path):
    """Captures that cannot be aligned may mean a long run through empty windows; the
    warning was printed only at the very end.  Here the replay is paced to take 30 s:
    the warning must be on stderr at once (the process is then stopped by a signal)."""
    import signal

    import numpy as np

    from mousedom.capture import DeviceInfo, NativeWriter
    from mousedom.capture.evemu import format_evemu

    t = np.arange(1, 3001) * 0.01  # 30 s of data
    d = np.ones(3000, dtype=int)
    mono = tmp_path / "a.mdcap"
    with NativeWriter(mono, [DeviceInfo(name="a", mouse="a", rel_xy=True)]) as w:
        w.motion(0, t, d, -d)
    rel = tmp_path / "b.evemu"  # wall clock times: cannot be aligned with since-boot ones
    rel.write_text(format_evemu(1.7e9 + t, d, -d, version=None))
    cfg = tmp_path / "two.yaml"
    cfg.write_text(TWO_MICE)
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "replay", "--config", str(cfg), "--capture",
         str(mono), "--capture", f"b={rel}", "-o", os.devnull, "--speed", "1"],
        stderr=subprocess.PIPE, text=True, env=mousedom_env(),
    )  # fmt: skip
    try:
        import selectors

        sel = selectors.DefaultSelector()
        sel.register(proc.stderr, selectors.EVENT_READ)
        assert sel.select(timeout=15), "no warning within 15 s of a 30 s replay"
        line = proc.stderr.readline()
        assert line.startswith("mousedom: warning:") and "cannot be aligned" in line
        assert proc.poll() is None  # still replaying
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        proc.stderr.close()


# A device's name as a capture may hold it: an OSC that sets the window title (ESC ] ...
# BEL), a CSI that clears the screen (ESC [ 2J), and the 8-bit CSI (U+009B).  Printed
# raw, the summary's "file (device)" column sent them to the terminal.
HOSTILE_NAME = "m\x1b]0;pwned\x07\x1b[2J\x9b31m"
SHOWN_NAME = r"m\x1b]0;pwned\x07\x1b[2J\x9b31m"
# Any C0 or C1 control character but the newline that ends a line.
_CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f-\x9f]")


def _no_control_characters(proc: subprocess.CompletedProcess) -> None:
    for stream in (proc.stdout, proc.stderr):
        assert not _CONTROL.search(stream), stream


def _libinput_device(node: str, name: str, t_usec: int) -> str:
    """One device of a ``libinput record`` file, its node and name as JSON strings (YAML
    reads JSON's escapes: the control characters are in the values, not the text)."""
    return (
        f"- node: {json.dumps(node)}\n  evdev:\n    name: {json.dumps(name)}\n"
        "    id: [3, 1, 2, 3]\n    codes:\n      0: [0]\n      2: [0, 1]\n"
        f"  events:\n  - evdev:\n    - [0, {t_usec}, 2, 0, 10]\n    - [0, {t_usec}, 0, 0, 0]\n"
    )


def _capture_named(tmp_path, kind: str, name: str):
    """A one-mouse capture of format ``kind`` whose device is called ``name``."""
    import numpy as np

    from mousedom.capture import DeviceInfo, NativeWriter
    from mousedom.capture.evemu import format_evemu

    t = np.arange(1, 51) * 0.01
    d = np.ones(50, dtype=int)
    if kind == "evemu":
        path = tmp_path / "m.evemu"
        path.write_bytes(format_evemu(t, d, -d, name=name).encode())
    elif kind == "libinput":
        path = tmp_path / "m.yml"
        path.write_text(
            "# libinput record\nversion: 1\nndevices: 1\ndevices:\n"
            + _libinput_device("/dev/input/event4", name, 10000)
        )
    else:
        path = tmp_path / "m.mdcap"
        with NativeWriter(path, [DeviceInfo(name=name, mouse="m", rel_xy=True)]) as w:
            w.motion(0, t, d, -d)
    return path


@pytest.mark.parametrize("kind", ["evemu", "libinput", "native"])
def test_control_characters_of_a_device_name_never_reach_the_terminal(tmp_path, kind):
    """replay's summary printed "FILE (DEVICE)" with the capture's device name raw; it
    is now escaped as `mousedom list` escapes a name, directly and after convert."""
    path = _capture_named(tmp_path, kind, HOSTILE_NAME)
    cfg = one_mouse_config(tmp_path)
    proc = run_mousedom("replay", "--config", str(cfg), "--capture", f"m={path}")
    assert proc.returncode == 0, proc.stderr
    _no_control_characters(proc)
    row = next(ln for ln in proc.stdout.splitlines() if ln.startswith("m "))
    assert row.endswith(f"{path} ({SHOWN_NAME})"), row
    native = tmp_path / "converted.mdcap"
    proc = run_mousedom("convert", "--capture", f"m={path}", "-o", str(native))
    assert proc.returncode == 0, proc.stderr
    _no_control_characters(proc)
    proc = run_mousedom("replay", "--config", str(cfg), "--capture", str(native))
    assert proc.returncode == 0, proc.stderr
    _no_control_characters(proc)
    assert f"{native} ({SHOWN_NAME})" in proc.stdout


def test_control_characters_of_a_recorded_node_never_reach_the_terminal(tmp_path):
    """A libinput file of two mice that match none: the message lists each device with
    its recorded node, which was printed raw (the names beside it were repr'd)."""
    rec = tmp_path / "two.yml"
    rec.write_text(
        "# libinput record\nversion: 1\nndevices: 2\ndevices:\n"
        + _libinput_device("/dev/input/\x1b]0;pwned\x07", "a\x1b[2J", 10000)
        + _libinput_device("/dev/input/event\x9b31m", "b\x07", 20000)
    )
    cfg = one_mouse_config(tmp_path)
    proc = run_mousedom("replay", "--config", str(cfg), "--capture", f"m={rec}")
    assert proc.returncode == 2
    _no_control_characters(proc)
    _one_error_line(proc.stderr, r"(/dev/input/\x1b]0;pwned\x07)", r"(/dev/input/event\x9b31m)")
