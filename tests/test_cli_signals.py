"""SIGTERM and SIGHUP on the command line (mousedom/hangup.py): a command that writes a file
leaves nothing half-written behind when `timeout`, systemd or a closed terminal ends it, and
then dies by the signal (an exit status of 143 is a failure to systemd, a death by SIGTERM
after `systemctl stop` is not);
record closes its file whole on a hangup; nohup's ignored SIGHUP stays ignored."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import mousedom_env
from test_evdev_fakes import motion_bytes
from test_record import fifos, read_capture, rig, start, stop

from mousedom.capture.evemu import format_evemu


def _big_evemu(folder: Path) -> Path:
    """An evemu recording that takes convert a second or more (about 15 MB)."""
    n = 200_000
    rng = np.random.default_rng(5)
    path = folder / "big.evemu"
    t = 1.0 + 0.001 * np.arange(n)
    path.write_text(format_evemu(t, rng.integers(1, 6, n), rng.integers(-5, 6, n)))
    return path


def _convert_signalled(folder: Path, source: Path, sig: int, preexec=None):
    out = folder / "out.mdcap"
    p = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "convert", "--capture", f"m={source}", "-o", str(out)],
        stderr=subprocess.PIPE, text=True, env=mousedom_env(), preexec_fn=preexec,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while not list(folder.glob(".out.mdcap.*")) and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    p.send_signal(sig)
    err = p.communicate(timeout=60)[1]
    return p.returncode, err, sorted(f.name for f in folder.iterdir() if f.name != source.name)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_convert_ended_by_a_signal_leaves_no_temporary_file(tmp_path, sig):
    """Killed by the default disposition, the full-size `.out.mdcap.XXXX.part` stayed."""
    source = _big_evemu(tmp_path)
    code, err, left = _convert_signalled(tmp_path, source, sig)
    assert left == [], (left, err)
    assert code == -sig, err  # dies by it after its cleanup, as a supervisor asked
    assert f"mousedom: terminated ({signal.Signals(sig).name})" in err
    assert "Traceback" not in err


def test_a_hangup_ignored_by_nohup_stays_ignored(tmp_path):
    source = _big_evemu(tmp_path)

    def nohup() -> None:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    code, err, left = _convert_signalled(tmp_path, source, signal.SIGHUP, nohup)
    assert code == 0 and left == ["out.mdcap"], err
    _, motion, _ = read_capture(tmp_path / "out.mdcap")
    assert len(motion["m"][0]) == 200_000


def test_record_closes_its_file_whole_on_a_hangup(tmp_path):
    """A closed terminal or a dropped ssh session: the recording stops as on SIGTERM, every
    count and the counters' NOTE chunk written (killed by SIGHUP before: no "done", the
    last quarter second and the dropped-frame counters lost)."""
    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "run.mdcap"
    p = start("record", "--config", str(rig(tmp_path, f)), "-o", str(out),
              "--status-interval", "0")  # fmt: skip
    dx = np.arange(300) % 7 - 3
    try:
        ws = _writers(f.values(), p)
        for w in ws:
            os.write(w, motion_bytes(time.monotonic(), dx, -dx, dt=0.001))
        time.sleep(0.5)
        err = stop(p, signal.SIGHUP)
        for w in ws:
            os.close(w)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "record: done" in err and f"record: wrote {out}" in err, err
    cap, motion, _ = read_capture(out)
    for name in ("a", "b"):
        assert motion[name][1] == dx.tolist() and motion[name][2] == (-dx).tolist()
    assert [st.frames for st in cap.stats] == [300, 300]


def _writers(paths, p: subprocess.Popen, timeout: float = 20.0) -> list[int]:
    """Writers of the FIFOs, once the recorder reads them (a blocking open would wait until
    then, and for ever had it stopped)."""
    deadline = time.monotonic() + timeout
    out = []
    for path in paths:
        while True:
            try:
                out.append(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
                break
            except OSError:  # ENXIO: no reader yet
                assert p.poll() is None and time.monotonic() < deadline, p.communicate()[1]
                time.sleep(0.01)
    return out


def test_record_to_stdout_streams_the_capture(tmp_path):
    """`record -o -` writes the capture to stdout, as convert's and replay's -o - do (it
    wrote a regular file named "-"); read back whole after a Ctrl-C."""
    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "piped.mdcap"
    with open(out, "wb") as sink:
        p = subprocess.Popen(
            [sys.executable, "-m", "mousedom", "record", "--config", str(rig(tmp_path, f)),
             "-o", "-", "--status-interval", "0"],
            stdout=sink, stderr=subprocess.PIPE, text=True, env=mousedom_env(), cwd=tmp_path,
        )  # fmt: skip
        dx = np.arange(200) % 5 - 2
        try:
            ws = _writers(f.values(), p)
            for w in ws:
                os.write(w, motion_bytes(time.monotonic(), dx, dx, dt=0.001))
            time.sleep(0.5)
            err = stop(p, signal.SIGINT)
            for w in ws:
                os.close(w)
        finally:
            p.kill()
    assert p.returncode == 0, err
    assert not (tmp_path / "-").exists()
    assert "record: wrote <stdout>" in err, err
    _, motion, _ = read_capture(out)
    assert motion["a"][1] == dx.tolist() and motion["b"][2] == dx.tolist()


def test_convert_to_a_reader_that_goes_away_is_an_error(tmp_path):
    """`convert -o - | head -c 1000`: the capture is the product, and its reader got a cut
    one: exit 1 and one line (exit 0 before, which pipefail could not see)."""
    source = _big_evemu(tmp_path)
    p = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "convert", "--capture", f"m={source}", "-o", "-"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=mousedom_env(),
    )  # fmt: skip
    assert p.stdout is not None and p.stderr is not None
    p.stdout.read(1000)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 1, err
    assert (
        err == "mousedom: error: <stdout>: the reader went away; the capture it got is cut short\n"
    )


def test_record_to_a_closed_stdout_is_one_line(tmp_path):
    """`record -o - >&-`: stdout is None to Python (an AttributeError traceback before)."""
    f = fifos(tmp_path, "a", "b")
    p = subprocess.run(
        [sys.executable, "-m", "mousedom", "record", "--config", str(rig(tmp_path, f)),
         "-o", "-"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=mousedom_env(),
        preexec_fn=lambda: os.close(1), timeout=60,
    )  # fmt: skip
    assert p.returncode == 2, p.stderr
    assert p.stderr == "mousedom: error: -o -: stdout is closed; redirect it, or give a file name\n"


def test_a_killed_recorder_keeps_the_counts_it_noted_lost(tmp_path):
    """kill -9 (a crash, a power cut) after frames with SYN_DROPPED: the file's notes say
    what they lost, up to the last flush (one NOTE at the end lost them all: the torn
    file's replay said nothing of the counts lost)."""
    from test_record import _events_with_drops

    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "run.mdcap"
    p = start("record", "--config", str(rig(tmp_path, f)), "-o", str(out),
              "--status-interval", "0")  # fmt: skip
    sent = {}
    try:
        ws = dict(zip(f, _writers(f.values(), p), strict=True))
        for k, (name, w) in enumerate(ws.items()):
            data, *sent[name] = _events_with_drops(40 + k, time.monotonic())
            os.write(w, data)
        time.sleep(0.8)  # past a flush (FLUSH_S)
        p.kill()
        p.wait(timeout=20)
        for w in ws.values():
            os.close(w)
    finally:
        p.kill()
    cap, motion, _ = read_capture(out)
    for i, dev in enumerate(cap.devices):
        st = cap.stats[i]
        kept_x, kept_y, lost_x, lost_y = sent[dev.mouse]
        assert (sum(motion[dev.mouse][1]), sum(motion[dev.mouse][2])) == (kept_x, kept_y)
        assert (st.lost_x, st.lost_y) == (lost_x, lost_y), dev.mouse
        assert st.dropped_frames > 0
