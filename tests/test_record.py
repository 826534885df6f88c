"""``mousedom record`` as a real process, with FIFO mice and a pty serial port."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import mousedom_env, run_mousedom
from test_evdev_fakes import motion_bytes

from mousedom.capture.native import NativeCapture


def rig(tmp_path: Path, mice: dict[str, str]) -> Path:
    """A config whose mice are evdev FIFOs (name -> fifo path) or serial ports ('serial:')."""
    lines = ["rate_hz: 100", "mice:"]
    for i, (name, where) in enumerate(mice.items()):
        lines.append(f"  {name}:")
        lines.append("    cpi: 800")
        lines.append(f"    mount: {{x: {0.1 * i}, y: {0.05 * (i % 2)}, yaw: 0}}")
        if where.startswith("serial:"):
            lines.append(f"    serial: {{port: {where[7:]}, baud: 115200}}")
        else:
            lines.append(f"    evdev: {{path: {where}}}")
    path = tmp_path / "rig.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def fifos(tmp_path: Path, *names: str) -> dict[str, str]:
    out = {}
    for n in names:
        p = tmp_path / f"{n}.fifo"
        os.mkfifo(p)
        out[n] = str(p)
    return out


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "mousedom", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=mousedom_env(),
    )


def stop(p: subprocess.Popen, sig: int) -> str:
    """Signal a running recorder and wait for it to end; its stderr."""
    p.send_signal(sig)
    return p.communicate(timeout=20)[1]


def interrupt_after_writes(p: subprocess.Popen, writers: dict[str, int]) -> str:
    """Let the recorder read what was written (0.4 s), Ctrl-C it, close the mice's FIFO
    writers; its stderr."""
    time.sleep(0.4)
    err = stop(p, signal.SIGINT)
    for w in writers.values():
        os.close(w)
    return err


def read_capture(path: Path):
    cap = NativeCapture(str(path))
    motion: dict[str, list] = {d.mouse: [[], [], []] for d in cap.devices}
    serial: dict[str, bytes] = {d.mouse: b"" for d in cap.devices}
    for feed in cap.feeds():
        for batch in feed.batches:
            for m in batch.motion:
                cols = motion[cap.devices[m.device].mouse]
                cols[0] += m.t.tolist()
                cols[1] += m.dx.tolist()
                cols[2] += m.dy.tolist()
            for s in batch.serial:
                serial[cap.devices[s.device].mouse] += b"".join(s.data)
    return cap, motion, serial


def frames(n: int, seed: int):
    rng = np.random.default_rng(seed)
    return rng.integers(-9, 10, n), rng.integers(-9, 10, n)


def test_sigint_closes_cleanly_with_every_count(tmp_path):
    f = fifos(tmp_path, "left", "right")
    out = tmp_path / "run.mdcap"
    p = start(
        "record", "--config", str(rig(tmp_path, f)), "-o", str(out), "--status-interval", "0.2"
    )
    try:
        ws = {n: os.open(path, os.O_WRONLY) for n, path in f.items()}  # waits for the reader
        sent = {}
        for seed, (n, w) in enumerate(ws.items()):
            dx, dy = frames(500, seed)
            sent[n] = (dx, dy)
            t0 = time.monotonic()
            for lo in range(0, 500, 100):  # several writes, as a mouse would
                os.write(
                    w, motion_bytes(t0 + lo * 0.001, dx[lo : lo + 100], dy[lo : lo + 100], dt=0.001)
                )
        time.sleep(0.6)
        err = stop(p, signal.SIGINT)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "recording left" in err and "right" in err
    assert "reports" in err and "Hz" in err and "record: done" in err
    assert f"record: wrote {out}\n" in err  # where it went, last (issue 29 item 6)
    assert "Traceback" not in err
    cap, motion, _ = read_capture(out)
    assert cap.warnings == []
    assert [d.mouse for d in cap.devices] == ["left", "right"]
    assert cap.header["config"].startswith("rate_hz: 100")
    for n, (dx, dy) in sent.items():
        t, gx, gy = motion[n]
        assert len(t) == 500 and gx == dx.tolist() and gy == dy.tolist()
        assert np.all(np.diff(t) > 0)
    assert cap.stats[0].frames == 500  # the NOTE chunk carried the source's counters
    for w in ws.values():
        os.close(w)


def test_kill9_leaves_a_readable_prefix(tmp_path):
    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "crash.mdcap"
    p = start("record", "--config", str(rig(tmp_path, f)), "-o", str(out), "--status-interval", "0")
    dxs = {}
    stop = threading.Event()

    def feed(name: str, path: str, seed: int) -> None:
        dx, dy = frames(100_000, seed)
        dxs[name] = dx
        w = os.open(path, os.O_WRONLY)
        try:
            i = 0
            while not stop.is_set() and i < len(dx):
                os.write(w, motion_bytes(time.monotonic(), dx[i : i + 8], dy[i : i + 8], dt=1e-6))
                i += 8
                time.sleep(0.002)
        except BrokenPipeError:
            pass  # the recorder was killed
        finally:
            os.close(w)

    threads = [
        threading.Thread(target=feed, args=(n, path, s)) for s, (n, path) in enumerate(f.items())
    ]
    for th in threads:
        th.start()
    time.sleep(1.2)
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=10)
    stop.set()
    for th in threads:
        th.join()
    p.stdout.close()
    p.stderr.close()
    cap, motion, _ = read_capture(out)  # must not raise: all but the last moments are there
    total = 0
    for n, (_, gx, _) in motion.items():
        k = len(gx)
        total += k
        assert gx == dxs[n][:k].tolist()  # a prefix of what was sent, nothing reordered
    assert total > 100  # ~1 s of recording at ~4000 reports/s per mouse, minus the last 0.25 s


def test_duration_unplug_and_reattach(tmp_path):
    f = fifos(tmp_path, "left", "right")
    out = tmp_path / "plug.mdcap"
    p = start(
        "record",
        "--config",
        str(rig(tmp_path, f)),
        "-o",
        str(out),
        "--duration",
        "2.5",
        "--status-interval",
        "0.5",
    )
    try:
        wr = os.open(f["right"], os.O_WRONLY)  # stays plugged the whole time
        w = os.open(f["left"], os.O_WRONLY)
        t0 = time.monotonic()
        os.write(w, motion_bytes(t0, [1, 2, 3], [0, 0, 0]))
        os.write(wr, motion_bytes(t0, [5], [5]))
        os.close(w)  # unplug
        time.sleep(0.3)
        w = os.open(f["left"], os.O_WRONLY)  # replug: blocks until the recorder reopens
        os.write(w, motion_bytes(time.monotonic(), [10, 20], [1, 1]))
        time.sleep(0.3)
        os.close(w)
        os.close(wr)
        _, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 0, err
    # The mouse is named once (regression: "left: left: device gone").
    assert "record: left: device gone" in err and "waiting for it to come back" in err
    assert "left: back" in err
    _, motion, _ = read_capture(out)
    assert motion["left"][1] == [1, 2, 3, 10, 20]
    assert motion["right"][1] == [5]


def test_serial_bytes_recorded_raw(tmp_path):
    """A downsampler on a pty: line noise then 20 MOTION packets; the file holds the exact
    bytes, which decode to the same 20 reports as the bytes that were sent."""
    from mousedom.sources import adns_protocol as P
    from mousedom.sources.adns_decode import packets_to_reports

    master, slave = os.openpty()
    port = os.ttyname(slave)
    f = fifos(tmp_path, "left")
    cfg = rig(tmp_path, {"left": f["left"], "adns": f"serial:{port}"})
    out = tmp_path / "serial.mdcap"
    p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0.2")
    packets = [
        P.encode_packet(
            P.Motion(
                seq=i, t_us=10_000 * (i + 1), dx=i, dy=2 * i, frames=12, squal_min=100, flags=0
            )
        )
        for i in range(20)
    ]
    payload = b"\x55\xaa noise \x00" + b"".join(packets)
    try:
        w = os.open(f["left"], os.O_WRONLY)
        time.sleep(0.3)  # the port is open once the FIFO is (sources open in order)
        for i in range(0, len(payload), 37):  # chunks that cut packets anywhere
            os.write(master, payload[i : i + 37])
            time.sleep(0.005)
        time.sleep(0.5)
        err = stop(p, signal.SIGTERM)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert f"adns (serial {port})" in err and f"adns {len(payload)} B 20 reports" in err
    cap, _, serial = read_capture(out)
    assert serial["adns"] == payload
    assert cap.devices[1].kind == "serial" and cap.devices[1].extra["port"] == port
    sent, _ = packets_to_reports([(0.0, payload)])
    got, _ = packets_to_reports([(0.0, serial["adns"])])
    assert len(got) == len(sent) == 20
    assert got.dx.tolist() == sent.dx.tolist() and got.dy.tolist() == sent.dy.tolist()
    assert sorted(abs(v) for v in got.dx.tolist() + got.dy.tolist()) == sorted(
        list(range(20)) + [2 * i for i in range(20)]
    )
    os.close(w)
    os.close(master)
    os.close(slave)


def test_user_errors(tmp_path):
    cfg = rig(tmp_path, {"left": str(tmp_path / "nope"), "right": str(tmp_path / "nope2")})
    r = run_mousedom("record", "--config", str(cfg), "-o", str(tmp_path / "x.mdcap"))
    assert r.returncode == 1
    assert "mice.left" in r.stderr and "no input device matches path=" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "x.mdcap").exists()
    f = fifos(tmp_path, "a", "b")
    r = run_mousedom(
        "record", "--config", str(rig(tmp_path, f)), "-o", str(tmp_path / "y"), "--duration", "-1"
    )
    assert r.returncode == 2 and "--duration" in r.stderr
    r = run_mousedom(
        "record",
        "--config",
        str(rig(tmp_path, f)),
        "-o",
        str(tmp_path / "no" / "dir" / "y"),
        "--duration",
        "0.1",
    )
    assert r.returncode == 1 and "cannot write" in r.stderr
    (tmp_path / "old.mdcap").write_bytes(b"precious")
    r = run_mousedom("record", "--config", str(rig(tmp_path, f)), "-o", str(tmp_path / "old.mdcap"))
    assert r.returncode == 2 and "exists" in r.stderr and "--force" in r.stderr
    assert (tmp_path / "old.mdcap").read_bytes() == b"precious"


def test_recording_replays_to_the_motion_that_was_made(tmp_path):
    """record -> replay: two mice pushed 1000 counts forward at 800 cpi = 31.75 mm."""
    f = fifos(tmp_path, "left", "right")
    cfg = rig(tmp_path, f)
    out = tmp_path / "straight.mdcap"
    p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0")
    try:
        ws = [os.open(path, os.O_WRONLY) for path in f.values()]
        t0 = time.monotonic()
        for w in ws:  # forward = -REL_Y (the mouse moves away from its user)
            os.write(w, motion_bytes(t0, [0] * 100, [-10] * 100, dt=0.008))
        time.sleep(0.5)
        err = stop(p, signal.SIGTERM)
    finally:
        p.kill()
    assert p.returncode == 0, err
    r = run_mousedom("replay", "--config", str(cfg), "--capture", str(out), "-o", "-")
    assert r.returncode == 0, r.stderr
    rows = [line.split(",") for line in r.stdout.strip().splitlines()]
    header, last = rows[0], rows[-1]
    x, y, theta = (float(last[header.index(k)]) for k in ("x", "y", "theta"))
    assert abs(x - 1000 / 800 * 0.0254) < 1e-9
    assert abs(y) < 1e-12 and abs(theta) < 1e-12
    for w in ws:
        os.close(w)


def test_a_replay_mouse_cannot_be_recorded(tmp_path):
    f = fifos(tmp_path, "a")
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "mice:\n"
        f"  a: {{cpi: 800, mount: {{x: 0, y: 0.1}}, evdev: {{path: {f['a']}}}}}\n"
        "  b: {cpi: 800, mount: {x: 0, y: -0.1}, replay: old.mdcap}\n"
    )
    r = run_mousedom("record", "--config", str(cfg), "-o", str(tmp_path / "z.mdcap"))
    assert r.returncode == 2 and "mice.b: a replay source cannot be recorded" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "z.mdcap").exists()


def test_an_ambiguous_rule_stops_record_with_the_candidates(tmp_path):
    """Regression: twin mice matched by name.  One line naming config, mouse and both
    candidates, exit 1, no file, no traceback (--root points at a fake machine)."""
    from test_evdev_fakes import add_device

    root = tmp_path / "machine"
    add_device(root, 1, "Twin", phys="usb-1/input0")
    add_device(root, 2, "Twin", phys="usb-2/input0")
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "mice:\n"
        "  a: {cpi: 800, mount: {x: 0, y: 0.1}, evdev: {name: Twin}}\n"
        "  b: {cpi: 800, mount: {x: 0, y: -0.1}, evdev: {name: Twin, phys: usb-2/input0}}\n"
    )
    out = tmp_path / "z.mdcap"
    r = run_mousedom("record", "--root", str(root), "--config", str(cfg), "-o", str(out))
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert f"{cfg}: mice.a: " in lines[0] and "2 devices match name='Twin'" in lines[0]
    assert "event1" in lines[0] and "event2" in lines[0]
    assert not out.exists()
    # Telling them apart fixes it: both FIFO nodes are recorded.
    cfg.write_text(cfg.read_text().replace("{name: Twin}", "{name: Twin, phys: usb-1/input0}"))
    r = run_mousedom(
        "record", "--root", str(root), "--config", str(cfg), "-o", str(out), "--duration", "0.2"
    )
    assert r.returncode == 0, r.stderr
    assert "event1" in r.stderr and "event2" in r.stderr


def test_a_missing_root_is_an_error(tmp_path):
    """Regression: a mistyped --root looked like a machine without mice (list: exit 0)."""
    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    for cmd in (["list"], ["record", "--config", str(cfg), "-o", str(tmp_path / "o")]):
        r = run_mousedom(*cmd, "--root", str(tmp_path / "typo"))
        assert r.returncode == 2 and f"--root {tmp_path / 'typo'}: no such directory" in r.stderr
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()
    r = run_mousedom("list", "--root", str(cfg))
    assert r.returncode == 2 and f"--root {cfg}: not a directory" in r.stderr


def test_a_file_that_cannot_grow_stops_with_one_line(tmp_path):
    """Regression: disk full / quota / ulimit -f mid-run said "internal error" (and a file
    size limit killed the recorder with SIGXFSZ and no word).  Now: one line naming the
    file and the OS's reason, exit 1, the file readable up to where it stopped."""
    import resource

    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "big.mdcap"
    limit = 32768

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    p = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "record", "--config", str(rig(tmp_path, f))]
        + ["-o", str(out), "--status-interval", "0", "--duration", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=mousedom_env(),
        preexec_fn=small_files,
    )
    dx, dy = frames(20_000, 1)
    try:
        w = os.open(f["a"], os.O_WRONLY)
        try:
            for lo in range(0, len(dx), 50):  # 2500 reports/s: several flushes fit
                t = time.monotonic()
                os.write(w, motion_bytes(t, dx[lo : lo + 50], dy[lo : lo + 50], dt=1e-4))
                time.sleep(0.02)
        except BrokenPipeError:
            pass  # the recorder stopped, as it should
        _, err = p.communicate(timeout=30)
        os.close(w)
    finally:
        p.kill()
    assert p.returncode == 1, err
    lines = [x for x in err.splitlines() if not x.startswith("record: ")]
    assert len(lines) == 1, err
    assert f"{out}: cannot write: File too large; recording stopped after" in lines[0]
    assert "internal error" not in err and "Traceback" not in err and "Exception" not in err
    assert out.stat().st_size <= limit
    cap, motion, _ = read_capture(out)
    got = motion["a"][1]
    assert 0 < len(got) < len(dx) and got == dx[: len(got)].tolist()


def test_a_closed_stderr_does_not_stop_the_recording(tmp_path):
    """Regression: ``record ... 2>&1 | head -2`` ended the recording at the first status
    line after head exited (EPIPE on stderr -> "internal error", exit 1)."""
    f = fifos(tmp_path, "a", "b")
    out = tmp_path / "quiet.mdcap"
    p = start(
        "record", "--config", str(rig(tmp_path, f)), "-o", str(out), "--status-interval", "0.05"
    )
    dx, dy = frames(300, 2)
    try:
        w = os.open(f["a"], os.O_WRONLY)
        p.stderr.readline()  # "recording a, b"
        p.stderr.close()  # the reader of our status lines goes away
        t0 = time.monotonic()
        for lo in range(0, 300, 30):
            os.write(w, motion_bytes(t0 + lo * 0.002, dx[lo : lo + 30], dy[lo : lo + 30], 0.002))
            time.sleep(0.05)  # status lines keep coming (and failing) meanwhile
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        p.wait(timeout=20)
        os.close(w)
    finally:
        p.kill()
    assert p.returncode == 0
    _, motion, _ = read_capture(out)
    assert motion["a"][1] == dx.tolist() and motion["a"][2] == dy.tolist()


def test_bad_status_interval_and_empty_output(tmp_path):
    cfg = str(rig(tmp_path, fifos(tmp_path, "a", "b")))
    for value in ("nan", "-1", "inf"):
        r = run_mousedom(
            "record", "--config", cfg, "-o", str(tmp_path / "o"), "--status-interval", value
        )
        assert r.returncode == 2 and "--status-interval: must be" in r.stderr, value
    r = run_mousedom("record", "--config", cfg, "-o", "")
    assert r.returncode == 2 and "-o/--output: empty file name" in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_stream_with_backward_stamps_records_a_replayable_file(tmp_path):
    """Regression: record wrote the backward stamps and replay refused the whole file."""
    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    out = tmp_path / "back.mdcap"
    p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0")
    try:
        w = os.open(f["a"], os.O_WRONLY)
        t0 = time.monotonic()
        os.write(w, motion_bytes(t0, [1, 2, 3], [0, 0, 0], dt=0.01))
        time.sleep(0.3)  # a later read, and a later chunk in the file
        os.write(w, motion_bytes(t0 - 5, [4, 5], [0, 0], dt=0.01))
        time.sleep(0.3)
        err = stop(p, signal.SIGINT)
        os.close(w)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "stamped-backwards 2" in err
    r = run_mousedom("replay", "--config", str(cfg), "--capture", str(out))
    assert r.returncode == 0, r.stderr
    _, motion, _ = read_capture(out)
    assert motion["a"][1] == [1, 2, 3, 4, 5] and motion["a"][0] == sorted(motion["a"][0])


def test_outputs_that_would_destroy_inputs_are_refused(tmp_path):
    """Regressions: with --force, -o CONFIG overwrote the rig config, -o FIFO recorded
    the recorder's own bytes as mouse events, and two mice on one FIFO split its
    reports between them silently."""
    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    text = cfg.read_text()
    r = run_mousedom("record", "--config", str(cfg), "-o", str(cfg), "--force")
    assert r.returncode == 2 and "is the config file" in r.stderr
    assert cfg.read_text() == text
    r = run_mousedom("record", "--config", str(cfg), "-o", f["a"], "--force", "--duration", "0.2")
    assert r.returncode == 1 and f"{f['a']}: is the device of mice.a" in r.stderr, r.stderr
    dup = rig(tmp_path, {"a": f["a"], "b": f["a"]})
    out = tmp_path / "dup.mdcap"
    r = run_mousedom("record", "--config", str(dup), "-o", str(out), "--duration", "0.2")
    assert r.returncode == 1 and "mice.a and mice.b both read" in r.stderr, r.stderr
    assert not out.exists() and "Traceback" not in r.stderr
    p = run_mousedom("list", "--config", str(dup))
    assert p.returncode == 1 and "b: matches" in p.stdout and "the same device as a" in p.stdout


def test_record_through_a_link_writes_nothing_anywhere(tmp_path):
    """Issue 11 item 4: `record -o` through a dangling link created its target; through a
    link to a file it truncated that file (with --force).  Both are refused."""
    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    target = tmp_path / "elsewhere.mdcap"
    dangling = tmp_path / "dangling.mdcap"
    dangling.symlink_to(target)
    r = run_mousedom("record", "--config", str(cfg), "-o", str(dangling), "--duration", "0.1")
    assert r.returncode != 0 and "symbolic link" in r.stderr and "Traceback" not in r.stderr
    assert not target.exists()
    target.write_bytes(b"precious")
    linked = tmp_path / "linked.mdcap"
    linked.symlink_to(target)
    r = run_mousedom(
        "record", "--config", str(cfg), "-o", str(linked), "--duration", "0.1", "--force"
    )
    assert r.returncode != 0 and "symbolic link" in r.stderr
    assert target.read_bytes() == b"precious"


def _events_with_drops(seed: int, t0: float) -> tuple[bytes, int, int, int, int]:
    """Raw input_event bytes of 300 frames, some cut by SYN_DROPPED (their counts, of
    either sign, are lost by the kernel's rule); (bytes, kept x, kept y, lost x, lost y)."""
    from mousedom.sources.events import EV_REL, EV_SYN, REL_X, REL_Y, SYN_DROPPED, SYN_REPORT
    from mousedom.sources.events import encode_input_events as enc

    rng = np.random.default_rng(seed)
    rows: list[tuple[float, int, int, int]] = []
    kept = [0, 0]
    lost = [0, 0]
    for k in range(300):
        t = t0 + k * 0.001
        dx, dy = (int(v) for v in rng.integers(-40, 41, 2))
        drop = rng.random() < 0.1
        rows += [(t, EV_REL, REL_X, dx), (t, EV_REL, REL_Y, dy)]
        if drop:
            rows.append((t, EV_SYN, SYN_DROPPED, 0))
        rows.append((t, EV_SYN, SYN_REPORT, 0))
        acc = lost if drop else kept
        acc[0] += dx
        acc[1] += dy
    t, typ, code, val = (np.array(c) for c in zip(*rows, strict=True))
    return enc(t, typ, code, val), kept[0], kept[1], lost[0], lost[1]


def test_record_then_replay_keeps_every_count_with_dropped_frames(tmp_path):
    """Round trip (issue 26): what ``record`` writes, SYN_DROPPED frames of any sign
    included, replays with exit 0, and its reports plus its counted losses are what the
    mouse sent, for several seeds."""
    for seed in range(3):
        d = tmp_path / str(seed)
        d.mkdir()
        f = fifos(d, "a", "b")
        cfg = rig(d, f)
        out = d / "run.mdcap"
        p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0")
        sent = {}
        try:
            ws = {n: os.open(path, os.O_WRONLY) for n, path in f.items()}
            for k, (n, w) in enumerate(ws.items()):
                data, *sent[n] = _events_with_drops(seed * 10 + k, time.monotonic())
                for lo in range(0, len(data), 24 * 97):  # reads cut anywhere in a frame
                    os.write(w, data[lo : lo + 24 * 97])
            err = interrupt_after_writes(p, ws)
        finally:
            p.kill()
        assert p.returncode == 0, err
        r = run_mousedom("replay", "--config", str(cfg), "--capture", str(out), "-o", "-")
        assert r.returncode == 0, r.stderr
        cap, motion, _ = read_capture(out)
        for i, dev in enumerate(cap.devices):
            st = cap.stats[i]
            assert [st.net_x, st.net_y, st.lost_x, st.lost_y] == sent[dev.mouse], (seed, dev)


@pytest.mark.parametrize("relative", [False, True])
def test_record_and_list_find_a_path_rule_alike_under_a_root(tmp_path, relative):
    """``list --root`` looked a rule's /dev/input path up in the root's tree, ``record
    --root`` on this machine (exit 1, "no input device matches"); and a udev link such as
    /dev/input/mousedom-left matched no device under a relative (or linked) root.  One
    rule for both now (discovery.locate)."""
    from test_evdev_fakes import add_device

    root = tmp_path / "machine"
    add_device(root, 0, "Left", phys="usb-1/input0",
               by_path=("pci-0000:00:14.0-usb-0:1:1.0-event-mouse",))  # fmt: skip
    add_device(root, 1, "Right", phys="usb-2/input0")
    os.symlink("event1", root / "dev" / "input" / "mousedom-right")
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "mice:\n"
        "  a: {cpi: 800, mount: {x: 0, y: 0.1},\n"
        "      evdev: {path: /dev/input/by-path/pci-0000:00:14.0-usb-0:1:1.0-event-mouse}}\n"
        "  b: {cpi: 800, mount: {x: 0, y: -0.1}, evdev: {path: /dev/input/mousedom-right}}\n"
    )
    where = "machine" if relative else str(root)
    r = run_mousedom("list", "--root", where, "--config", str(cfg), cwd=str(tmp_path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "a -> " in r.stdout and "b -> " in r.stdout
    out = tmp_path / "z.mdcap"
    r = run_mousedom("record", "--root", where, "--config", str(cfg), "-o", str(out),
                     "--duration", "0.2", cwd=str(tmp_path))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "event0" in r.stderr and "event1" in r.stderr


@pytest.mark.parametrize("cut", [1, 2])
def test_record_stopped_mid_frame_keeps_the_open_frames_counts(tmp_path, cut):
    """Stopped with Ctrl-C while a frame's events had come but not its SYN_REPORT: the
    counts were neither written nor counted as unterminated (an unplug kept them)."""
    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    out = tmp_path / "run.mdcap"
    p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0")
    try:
        ws = {n: os.open(path, os.O_WRONLY) for n, path in f.items()}
        whole = motion_bytes(time.monotonic(), [3, -4, 5], [7, 8, -9])
        os.write(ws["a"], whole)
        os.write(ws["b"], whole)
        # then a frame's REL_X (and REL_Y) without its SYN_REPORT: 24-byte events
        os.write(ws["a"], motion_bytes(time.monotonic(), [53], [-11])[: 24 * cut])
        err = interrupt_after_writes(p, ws)
    finally:
        p.kill()
    assert p.returncode == 0, err
    cap, _, _ = read_capture(out)
    net = {dev.mouse: (cap.stats[i].net_x, cap.stats[i].net_y) for i, dev in enumerate(cap.devices)}
    assert net["b"] == (4, 6)
    assert net["a"] == (4 + 53, 6 + (-11 if cut == 2 else 0)), net


def test_a_frame_beyond_32_bits_stops_the_recording_with_what_came_before_it(tmp_path):
    """A frame whose REL_X events sum past 2**31 (no mouse sends one; a FIFO may): the
    whole read was refused by the writer, the file held no report, and the message named
    "(input_event stream)" with exit 2.  Now the reports before it are kept, the line names
    the mouse and its device, and the exit is record's 1 for a recording that stopped."""
    from mousedom.sources.events import encode_input_events

    f = fifos(tmp_path, "a", "b")
    cfg = rig(tmp_path, f)
    out = tmp_path / "run.mdcap"
    p = start("record", "--config", str(cfg), "-o", str(out), "--status-interval", "0")
    try:
        ws = {n: os.open(path, os.O_WRONLY) for n, path in f.items()}
        t0 = time.monotonic()
        big = 2**31 - 1
        frame = encode_input_events(np.full(3, t0 + 0.1), np.array([2, 2, 0]),
                                    np.array([0, 0, 0]), np.array([big, big, 0]))  # fmt: skip
        os.write(ws["a"], motion_bytes(t0, [3, 4], [5, 6]) + frame  # one frame: 2 REL_X
                 + motion_bytes(t0 + 0.2, [7], [8]))  # fmt: skip
        err = p.communicate(timeout=20)[1]
        for w in ws.values():
            os.close(w)
    finally:
        p.kill()
    assert p.returncode == 1, err
    assert "Traceback" not in err
    assert "record: a (" in err and "beyond the native format's signed 32 bits" in err, err
    cap, _, _ = read_capture(out)
    a = next(i for i, d in enumerate(cap.devices) if d.mouse == "a")
    assert (cap.stats[a].net_x, cap.stats[a].net_y) == (7, 11)
