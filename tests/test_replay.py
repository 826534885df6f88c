"""``mousedom replay`` and ``mousedom convert`` as a user runs them (real processes)."""

from __future__ import annotations

import io
import math
import os
import pty
import subprocess
import sys

import numpy as np
import pytest
from capture_helpers import (
    EXTERNAL,
    GOLDEN,
    PS2,
    drain,
    external_dir,
    one_mouse_config,
    replay_ps2,
)
from conftest import mousedom_env, run_mousedom

from mousedom.capture import DeviceInfo, NativeWriter, assign, open_capture, read_reports
from mousedom.capture.evemu import format_evemu
from mousedom.capture.libinput import format_libinput
from mousedom.capture.replay import CsvSink, Replay, csv_columns, read_csv
from mousedom.config import parse_config
from mousedom.fusion import sim


def _ok(proc):
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return proc


def _fails(proc, *needles):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mousedom: error:"), proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ real recordings


@pytest.mark.parametrize("row", EXTERNAL, ids=[r[0].split("__")[1] for r in EXTERNAL])
def test_every_external_capture_replays(tmp_path, row):
    name, _, _, motion, net_x, net_y, path_x, path_y = row
    cfg = one_mouse_config(tmp_path)
    proc = _ok(
        run_mousedom("replay", "--config", str(cfg), "--capture", f"m={external_dir() / name}")
    )
    out = proc.stdout
    assert "duration" in out and "path length" in out and "final pose" in out
    row_m = next(ln.split() for ln in out.splitlines() if ln.startswith("m "))
    assert row_m[1] == str(motion)
    assert row_m[3:7] == [str(net_x), str(net_y), str(path_x), str(path_y)]


def test_golden_trajectory_ps2_mouse(tmp_path):
    """Regression: PS/2 mouse replay against tests/golden (MOUSEDOM_REGEN_GOLDEN=1 rewrites)."""
    cfg = GOLDEN / "ps2_generic_mouse.yaml"
    out = tmp_path / "ps2.csv"
    _ok(replay_ps2(cfg, "-o", str(out)))
    golden = GOLDEN / "ps2_generic_mouse.csv"
    if os.environ.get("MOUSEDOM_REGEN_GOLDEN") == "1":
        golden.write_text(out.read_text())
    got, want = read_csv(out.read_text()), read_csv(golden.read_text())
    assert list(got) == csv_columns(("m",))
    # A golden file written before a column was added is compared on the columns it has.
    assert set(want) <= set(got)
    for k in want:
        # the covariance in exponent form, 7 significant digits; the rest fixed-point
        tol = {"rtol": 1e-6, "atol": 1e-300} if k.startswith("cov_") else {"rtol": 0, "atol": 2e-9}
        np.testing.assert_allclose(got[k], want[k], err_msg=k, **tol)


def test_evemu_to_native_to_replay_gives_identical_poses(tmp_path):
    cfg = one_mouse_config(tmp_path)
    for name in (PS2, "evemu-devices__Ultrathin_Touch_Mouse.events"):
        src = external_dir() / name
        native = tmp_path / "x.mdcap"
        _ok(
            run_mousedom(
                "convert", "--capture", f"m={src}", "-o", str(native), "--config", str(cfg)
            )
        )
        a = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={src}", "-o", "-"))
        b = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(native), "-o", "-"))
        assert a.stdout == b.stdout and a.stdout.count("\n") > 900


def test_csv_to_stdout_last_row_holds_every_count(tmp_path):
    cfg = one_mouse_config(tmp_path)
    src = external_dir() / PS2
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={src}", "-o", "-"))
    lines = proc.stdout.splitlines()
    assert lines[0] == ",".join(csv_columns(("m",)))
    assert lines[0] == (
        "t,x,y,theta,vx,vy,omega,used,ok,consistent,state_m,reason_m,"
        "cov_xx,cov_xy,cov_xt,cov_yy,cov_yt,cov_tt,scale_x_m,scale_y_m"
    )
    # In process: the windows' counts add up to the capture's net counts.
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    batches = []
    rp = Replay(config, assign(config, [("m", str(src))]))
    buf = io.StringIO()
    sink = CsvSink(buf, config.names)
    summary = rp.run(lambda b: (batches.append(b), sink(b)))
    counts = sum(b.counts.sum(axis=0) for b in batches)
    assert counts[0].tolist() == [-5424.0, -929.0]
    assert buf.getvalue() == proc.stdout
    last = lines[-1].split(",")
    assert float(last[0]) == pytest.approx(summary.final["t"])
    assert float(last[3]) == pytest.approx(summary.final["theta"], abs=1e-9)
    assert float(last[0]) >= summary.duration


# ------------------------------------------------------------------ simulated rigs


def _sim_native(tmp_path, chunk_reports=2000, fault=None):
    """A three-mouse capture; ``fault(rig) -> faulty rig`` for the mice as they really were."""
    rig = sim.three_mouse_rig(cpi=800.0, report_hz=250.0)
    traj = sim.sequence(sim.straight(0.5), sim.turn(math.pi / 2), sim.arc(0.4, math.pi / 3))
    res = sim.simulate(fault(rig) if fault else rig, traj, seed=4, t_start=1000.0)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(sim.rig_yaml(rig))
    devices = [DeviceInfo(name=f"usb {m.name}", mouse=m.name, rel_xy=True) for m in rig.mice]
    path = tmp_path / "rig.mdcap"
    with NativeWriter(
        path,
        devices,
        time_base="monotonic",
        chunk_reports=chunk_reports,
        config_text=cfg.read_text(),
    ) as w:
        step = 0.25
        end = res.motion.starts[-1]
        k = 0
        while k * step <= end - 1000.0 + 1:
            lo, hi = 1000.0 + k * step, 1000.0 + (k + 1) * step
            for i, m in enumerate(rig.mice):
                r = res.reports[m.name]
                sel = (r.t >= lo) & (r.t < hi)
                w.motion(i, r.t[sel], r.dx[sel].astype(int), r.dy[sel].astype(int))
            w.sync(np.nextafter(hi, -np.inf))
            k += 1
    return rig, res, cfg, path


def test_simulated_rig_native_replay_matches_truth_and_batch_tracker(tmp_path):
    rig, res, cfg, path = _sim_native(tmp_path)
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(path), "-o", "-"))
    data = read_csv(proc.stdout)
    truth = res.truth(res.motion.starts[-1])[0]
    final = np.array([data["x"][-1], data["y"][-1], data["theta"][-1]])
    assert np.hypot(*(final[:2] - truth[:2])) < 0.01  # 1 cm after ~1.3 m of driving
    assert abs(final[2] - truth[2]) < 0.01
    # Streaming through the engine equals one batch through the tracker.
    from mousedom.fusion.tracker import Tracker

    tracker = Tracker(sim.rig_config(rig), t0=min(r.t[0] for r in res.reports.values()))
    for name, r in res.reports.items():
        tracker.push(name, r.t, r.dx, r.dy)
    batch = tracker.finish()
    assert final == pytest.approx([batch.x[-1], batch.y[-1], batch.theta[-1]], abs=1e-6)
    # Time base: monotonic times are kept as they are.
    assert data["t"][0] > 1000.0


def test_replay_csv_names_the_excluded_mouse_and_robust_false_turns_it_off(tmp_path):
    """Issue 16: the replay CSV's health columns show the lifted mouse excluded (and why)
    while it was lifted, and the config's switch gives plain least squares."""
    import dataclasses

    def lift(rig):
        front = dataclasses.replace(rig.mice[0], lost=((1000.8, 1001.6),))
        return dataclasses.replace(rig, mice=(front, *rig.mice[1:]))

    rig, res, cfg, path = _sim_native(tmp_path, fault=lift)
    data = read_csv(_ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(path),
                                     "-o", "-")).stdout)  # fmt: skip
    assert {"consistent", "state_front", "reason_front", "state_right"} <= set(data)
    # Silent, it is first held as late (a late mouse is silent too), for at most late_s
    # (0.05 s by default) and a window; then excluded until it is put down.
    held = (data["t"] > 1000.81) & (data["t"] < 1001.6)
    assert (
        np.isin(data["state_front"][held], (2, 4)).all() and (data["reason_front"][held] == 2).all()
    )
    assert (data["state_front"][held & (data["t"] > 1000.8 + 0.05 + 0.021)] == 2).all()
    assert (data["used"][held] == 2).all() and (data["state_left"] == 0).all()
    truth = res.truth(res.motion.starts[-1])[0]
    assert np.hypot(data["x"][-1] - truth[0], data["y"][-1] - truth[1]) < 0.01
    off = tmp_path / "off.yaml"
    off.write_text(cfg.read_text() + "robust: false\n")
    plain = read_csv(_ok(run_mousedom("replay", "--config", str(off), "--capture", str(path),
                                      "-o", "-")).stdout)  # fmt: skip
    assert (plain["state_front"] == 0).all() and (plain["used"] == 3).all()
    assert np.hypot(plain["x"][-1] - truth[0], plain["y"][-1] - truth[1]) > 0.05
    flag = read_csv(_ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(path),
                                     "--no-robust", "-o", "-")).stdout)  # fmt: skip
    assert all(np.array_equal(flag[k], plain[k]) for k in plain)  # the switch = the config


def test_csv_covariance_and_scale_columns_read_back_as_the_batches_hold_them(tmp_path):
    """Issue 31: the pose covariance (upper triangle of cov over x, y, theta, in m and rad
    as the pose columns) and each mouse's learnt scale per axis are columns; read back,
    they are the batches' values to the printed precision (7 significant digits, 6
    decimals)."""
    from mousedom.fusion.posebatch import PoseBatch

    rig, res, cfg, path = _sim_native(tmp_path)
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    batches = []
    buf = io.StringIO()
    sink = CsvSink(buf, config.names)
    Replay(config, assign(config, [(None, str(path))])).run(lambda b: (batches.append(b), sink(b)))
    b = PoseBatch.concat(batches)
    data = read_csv(buf.getvalue())
    assert list(data) == csv_columns(config.names)
    assert len(data["t"]) == len(b) > 100
    upper = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for name, (i, j) in zip(("xx", "xy", "xt", "yy", "yt", "tt"), upper, strict=True):
        col = data[f"cov_{name}"]
        # the batch's cov is symmetric: the column is either off-diagonal twin
        for got_from in (b.cov[:, i, j], b.cov[:, j, i]):
            np.testing.assert_allclose(col, got_from, rtol=5e-7, atol=0, err_msg=name)
    assert (data["cov_xx"] > 0).all() and (data["cov_tt"] > 0).all()
    assert (data["cov_xy"] ** 2 <= data["cov_xx"] * data["cov_yy"] * (1 + 1e-5)).all()
    for k, name in enumerate(config.names):
        for axis, col in enumerate(("scale_x", "scale_y")):
            np.testing.assert_allclose(data[f"{col}_{name}"], b.scales()[:, k, axis], atol=5e-7)
    # A learnt scale (the engine's, or one set here) is written per mouse and axis.
    rng = np.random.default_rng(5)
    learnt = 1 + rng.normal(0, 0.04, b.counts.shape)
    b.scale = learnt
    buf = io.StringIO()
    CsvSink(buf, config.names)(b)
    data = read_csv(buf.getvalue())
    for k, name in enumerate(config.names):
        assert np.abs(data[f"scale_x_{name}"] - learnt[:, k, 0]).max() <= 5e-7
        assert np.abs(data[f"scale_y_{name}"] - learnt[:, k, 1]).max() <= 5e-7


def test_multi_device_file_without_name_maps_by_config(tmp_path):
    rng = np.random.default_rng(8)
    n = 300
    t = np.cumsum(rng.uniform(0.002, 0.01, n))
    devs = [
        ("left", t, rng.integers(-5, 5, n), rng.integers(-20, 0, n)),
        ("right", t + 0.001, rng.integers(-5, 5, n), rng.integers(-20, 0, n)),
    ]
    rec = tmp_path / "two.yml"
    rec.write_text(format_libinput(devs))
    cfg = tmp_path / "two.yaml"
    cfg.write_text(
        "rate_hz: 50\nmice:\n"
        "  a:\n    cpi: 400\n    mount: {x: 0.0, y: 0.1}\n    evdev: {name: left}\n"
        "  b:\n    cpi: 400\n    mount: {x: 0.0, y: -0.1}\n    evdev: {name: right}\n"
    )
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(rec)))
    rows = {ln.split()[0]: ln.split() for ln in proc.stdout.splitlines() if ln[:2] in ("a ", "b ")}
    assert rows["a"][3] == str(int(devs[0][2].sum())) and rows["b"][3] == str(int(devs[1][2].sum()))
    # Through convert: same poses from the native file.
    native = tmp_path / "two.mdcap"
    _ok(run_mousedom("convert", "--capture", str(rec), "-o", str(native)))
    a = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(rec), "-o", "-"))
    b = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(native), "-o", "-"))
    assert a.stdout == b.stdout


def test_epoch_files_are_rebased_together_relative_ones_kept(tmp_path):
    t = np.arange(1, 201) * 0.01
    d = np.ones(200, dtype=int)
    (tmp_path / "a.evemu").write_text(format_evemu(1.7e9 + t, d, -d, version=None))
    (tmp_path / "b.evemu").write_text(format_evemu(1.7e9 + 0.5 + t, d, -d, version=None))
    cfg = tmp_path / "r.yaml"
    cfg.write_text(
        "rate_hz: 100\nmice:\n  a: {cpi: 400, mount: {x: 0, y: 0.1}}\n"
        "  b: {cpi: 400, mount: {x: 0, y: -0.1}}\n"
    )
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    reps, stats, warnings = read_reports(
        config, [("a", str(tmp_path / "a.evemu")), ("b", str(tmp_path / "b.evemu"))]
    )
    assert reps["a"].t[0] == pytest.approx(0.0, abs=1e-6)
    assert reps["b"].t[0] == pytest.approx(0.5, abs=1e-6)
    assert stats["a"].net_x == 200 and not warnings
    # A relative file keeps its times.
    (tmp_path / "c.evemu").write_text(format_evemu(3.0 + t, d, -d))
    reps, _, warnings = read_reports(
        config, [("a", str(tmp_path / "c.evemu")), ("b", str(tmp_path / "b.evemu"))]
    )
    assert reps["a"].t[0] == pytest.approx(3.01)
    assert warnings and "cannot be aligned" in warnings[0]


# ------------------------------------------------------------------ errors


def test_capture_naming_a_mouse_the_config_lacks(tmp_path):
    cfg = one_mouse_config(tmp_path)
    _fails(
        run_mousedom("replay", "--config", str(cfg), "--capture", f"nosuch={external_dir() / PS2}"),
        "no mouse 'nosuch'",
        "its mice: m",
    )


def test_config_mouse_without_capture(tmp_path):
    cfg = tmp_path / "two.yaml"
    cfg.write_text(
        "mice:\n  a: {cpi: 400, mount: {x: 0, y: 0.1}}\n  b: {cpi: 400, mount: {x: 0, y: -0.1}}\n"
    )
    _fails(
        run_mousedom("replay", "--config", str(cfg), "--capture", f"a={external_dir() / PS2}"),
        "no capture for mouse 'b'",
    )


def test_garbage_capture_and_missing_file(tmp_path):
    cfg = one_mouse_config(tmp_path)
    bad = tmp_path / "bad.evemu"
    bad.write_text("E: 1.0 0002 0000 1\nE: 1.0 0000 0000 0\nthis is not evemu\n")
    _fails(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={bad}"), "bad.evemu:3:")
    _fails(
        run_mousedom("replay", "--config", str(cfg), "--capture", f"m={tmp_path}/none.evemu"),
        "not found",
    )
    png = tmp_path / "x.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    _fails(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={png}"), "x.png")
    _fails(
        replay_ps2(
            cfg,
            "--speed",
            "-1",
        ),
        "--speed",
    )


def test_truncated_native_replays_with_a_warning(tmp_path):
    rig, res, cfg, path = _sim_native(tmp_path, chunk_reports=300)
    data = path.read_bytes()
    cut = tmp_path / "cut.mdcap"
    cut.write_bytes(data[: len(data) * 2 // 3 + 7])
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(cut)))
    assert "warning" in proc.stderr and "unfinished chunk" in proc.stderr
    assert "torn tail" in proc.stdout


# ------------------------------------------------------------------ plot, speed, progress


def test_plot_writes_a_png(tmp_path):
    cfg = one_mouse_config(tmp_path)
    png = tmp_path / "p.png"
    p = _ok(replay_ps2(cfg, "--plot", str(png)))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert f"replay: wrote the plot to {png}\n" in p.stderr  # issue 29 item 6


def test_every_file_written_is_named_on_stderr(tmp_path):
    """Issue 29 item 6: -o FILE and --plot each say where they wrote, one line each on
    stderr with the path as given; -o - (stdout) says nothing of the kind."""
    cfg = one_mouse_config(tmp_path)
    csv, png = "poses.csv", "plot.png"  # relative, as a user types them
    p = _ok(replay_ps2(cfg, "-o", csv, "--plot", png, cwd=tmp_path))
    lines = p.stderr.splitlines()
    assert f"replay: wrote the poses (CSV) to {csv}" in lines
    assert f"replay: wrote the plot to {png}" in lines
    assert (tmp_path / csv).stat().st_size > 0 and (tmp_path / png).stat().st_size > 0
    p = _ok(replay_ps2(cfg, "-o", "-"))
    assert "wrote" not in p.stderr


def test_plot_without_matplotlib_says_how_to_install(tmp_path):
    fake = tmp_path / "fake"
    (fake / "matplotlib").mkdir(parents=True)
    (fake / "matplotlib" / "__init__.py").write_text("raise ImportError('no matplotlib')\n")
    env = mousedom_env()
    env["PYTHONPATH"] = str(fake) + os.pathsep + env["PYTHONPATH"]
    cfg = one_mouse_config(tmp_path)
    line = _fails(
        replay_ps2(
            cfg,
            "--plot",
            str(tmp_path / "p.png"),
            env=env,
        ),
        "pip install 'mousedom[plot]'",
    )
    assert not (tmp_path / "p.png").exists() and line


def test_speed_replays_a_short_capture(tmp_path):
    t = np.arange(1, 31) * 0.01
    d = np.ones(30, dtype=int)
    cap = tmp_path / "s.evemu"
    cap.write_text(format_evemu(t, d, d))
    cfg = one_mouse_config(tmp_path)
    proc = _ok(
        run_mousedom(
            "replay", "--config", str(cfg), "--capture", f"m={cap}", "-o", "-", "--speed", "20"
        )
    )
    rows = read_csv(proc.stdout)
    # Windows of 10 ms from the first event (0.01 s) to the last report (0.30 s).
    assert len(rows["t"]) == 29 and rows["t"][-1] == pytest.approx(0.30)


def test_progress_bar_on_a_terminal_only(tmp_path):
    cfg = one_mouse_config(tmp_path)
    args = [
        sys.executable,
        "-m",
        "mousedom",
        "replay",
        "--config",
        str(cfg),
        "--capture",
        f"m={external_dir() / PS2}",
        "-o",
        str(tmp_path / "o.csv"),
    ]
    master, slave = pty.openpty()
    try:
        proc = subprocess.run(
            args, stderr=slave, stdout=subprocess.PIPE, env=mousedom_env(), timeout=60
        )
        os.close(slave)
        seen = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                break
            if not chunk:
                break
            seen += chunk
    finally:
        os.close(master)
    assert proc.returncode == 0
    assert b"replay [" in seen and b"%" in seen
    plain = run_mousedom(*args[3:])
    assert "replay [" not in plain.stderr


def test_native_stats_survive_convert(tmp_path):
    src = external_dir() / "evemu-devices__Saitek_Cyborg_RAT5_Mouse.events"
    native = tmp_path / "s.mdcap"
    p = _ok(run_mousedom("convert", "--capture", f"m={src}", "-o", str(native), "--no-compress"))
    assert p.stdout == "" and f"{native}: 1 devices" in p.stderr  # where it wrote, on stderr
    cap = drain(native)
    assert cap.stats[0].skipped == 13 and cap.stats[0].net_x == -111
    assert cap.devices[0].mouse == "m" and cap.devices[0].name == "Saitek Cyborg R.A.T.5 Mouse"


def test_serial_adns_bytes_replay_through_the_daemon_decoder(tmp_path):
    from mousedom.sources import adns_protocol as P

    rng = np.random.default_rng(11)
    n = 400
    dx = rng.integers(-30, 30, n)
    dy = rng.integers(0, 60, n)  # sensor +dy = forward
    wire = b"".join(
        P.encode_packet(
            P.Motion(
                seq=k,
                t_us=5000 + 10_000 * k,
                dx=int(dx[k]),
                dy=int(dy[k]),
                frames=12,
                squal_min=40,
                flags=0,
            )
        )
        for k in range(n)
    )
    # Cut the byte stream anywhere, as reads from a port do; arrival 0.5 to 3 ms after.
    cuts = np.sort(rng.choice(np.arange(1, len(wire)), 150, replace=False))
    pieces = np.split(np.frombuffer(wire, np.uint8), cuts)
    ends = np.cumsum([len(p) for p in pieces])
    times = []
    for e in ends:
        k = wire.count(b"\0", 0, e) - 1  # index of the last complete packet in the read
        times.append(20.0 + 0.005 + 0.01 * max(k, 0) + 0.0005 + 0.0025 * rng.random())
    times = np.maximum.accumulate(times)
    p = tmp_path / "adns.mdcap"
    dev = DeviceInfo(name="downsampler", kind="serial", mouse="floor")
    with NativeWriter(p, [dev], time_base="monotonic") as w:
        w.serial_many(0, times.tolist(), [bytes(x) for x in pieces])
    cfg = one_mouse_config(tmp_path, name="floor")
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", str(p)))
    row = next(ln.split() for ln in proc.stdout.splitlines() if ln.startswith("floor "))
    assert row[1] == str(n)
    # REL_X = Delta_X, REL_Y = -Delta_Y (adns_decode): every count arrives.
    assert row[3:5] == [str(int(dx.sum())), str(int(-dy.sum()))]
    assert row[8] == "0"  # no packet lost


def test_unknown_devices_and_non_mice(tmp_path):
    from test_capture_libinput import KEYBOARD

    t = np.array([0.01, 0.02])
    rec = tmp_path / "kb.yml"
    rec.write_text(
        format_libinput([("gaming mouse", t, np.array([1, 1]), np.array([0, 0]))]) + KEYBOARD
    )
    cfg = one_mouse_config(tmp_path)
    # Given without NAME=, the file's mouse matches no mouse of the config.
    _fails(
        run_mousedom("replay", "--config", str(cfg), "--capture", str(rec)),
        "no device ('gaming mouse' (/dev/input/event5)) matches a mouse",
        "give it as NAME=",
    )
    # Given by name, its one motion device is taken; a keyboard-only file is refused.
    _ok(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={rec}"))
    kb_only = tmp_path / "kbonly.yml"
    kb_only.write_text(
        rec.read_text().split("- node:")[0] + "- node:" + KEYBOARD.split("- node:")[1]
    )
    _fails(
        run_mousedom("replay", "--config", str(cfg), "--capture", f"m={kb_only}"),
        "no REL_X/REL_Y motion",
    )


def test_convert_refuses_to_overwrite_its_input_and_ambiguous_names(tmp_path):
    src = tmp_path / "a.evemu"
    src.write_text(format_evemu(np.array([1.0]), np.array([1]), np.array([1])))
    _fails(run_mousedom("convert", "--capture", f"m={src}", "-o", str(src)), "overwrite")
    two = tmp_path / "two.yml"
    two.write_text(
        format_libinput(
            [
                ("l", np.array([0.1]), np.array([1]), np.array([0])),
                ("r", np.array([0.1]), np.array([1]), np.array([0])),
            ]
        )
    )
    _fails(
        run_mousedom("convert", "--capture", f"m={two}", "-o", str(tmp_path / "o.mdcap")),
        "2 motion devices",
    )


def test_a_capture_without_motion_warns(tmp_path):
    src = tmp_path / "btn.evemu"
    src.write_text("E: 1.0 0001 0110 1\nE: 1.0 0000 0000 0\n")
    cfg = one_mouse_config(tmp_path)
    proc = _ok(run_mousedom("replay", "--config", str(cfg), "--capture", f"m={src}", "-o", "-"))
    assert proc.stdout == ",".join(csv_columns(("m",))) + "\n"
    assert "no motion reports" in proc.stderr


def test_convert_keeps_serial_bytes(tmp_path):
    p = tmp_path / "in.mdcap"
    devs = [
        DeviceInfo(name="m", mouse="m", rel_xy=True),
        DeviceInfo(name="adns", kind="serial", mouse="floor"),
    ]
    with NativeWriter(p, devs) as w:
        w.motion(0, [1.0, 2.0], [1, 2], [3, 4])
        w.serial_many(1, [1.5, 1.7], [b"\x01\x02", b"\x00"])
    out = tmp_path / "out.mdcap"
    _ok(run_mousedom("convert", "--capture", str(p), "-o", str(out)))
    cap = open_capture(out)
    pieces = [
        (float(t), d)
        for f in cap.feeds()
        for b in f.batches
        for s in b.serial
        for t, d in zip(s.t, s.data, strict=True)
    ]
    assert pieces == [(1.5, b"\x01\x02"), (1.7, b"\x00")]
    assert [d.kind for d in cap.devices] == ["evdev", "serial"]


def test_two_epoch_files_stay_aligned_through_replay(tmp_path):
    """Two epoch-stamped files whose clocks differ by 1.25 s replay exactly like the same
    reports on one relative time base (b starting 1.25 s after a); rebasing each file to
    its own first event would start both at 0 and give other poses."""
    rng = np.random.default_rng(21)
    n = 300
    ta = 0.0033 + np.cumsum(rng.uniform(0.004, 0.012, n))
    tb = 1.25 + 0.0033 + np.cumsum(rng.uniform(0.004, 0.012, n))
    da = (rng.integers(-3, 4, n), rng.integers(-9, 1, n))
    db = (rng.integers(-3, 4, n), rng.integers(-9, 1, n))
    epoch = 1_700_000_000.0
    files = {}
    for tag, base in (("epoch", epoch), ("rel", 0.0)):
        # The same data, stamped on one clock: only the earliest event is the origin.
        files[tag] = []
        for name, t, d in (("a", ta, da), ("b", tb, db)):
            p = tmp_path / f"{tag}_{name}.evemu"
            p.write_text(format_evemu(base + t, *d, version=None if base else "1.3"))
            files[tag].append(f"{name}={p}")
    cfg = tmp_path / "r.yaml"
    cfg.write_text(
        "rate_hz: 50\nmodel: lsq\nmice:\n  a: {cpi: 400, mount: {x: 0.05, y: 0.1}}\n"
        "  b: {cpi: 400, mount: {x: -0.05, y: -0.1}}\n"
    )
    out = {}
    for tag, caps in files.items():
        args = [w for c in caps for w in ("--capture", c)]
        proc = _ok(run_mousedom("replay", "--config", str(cfg), *args, "-o", "-"))
        out[tag] = read_csv(proc.stdout)
    # The relative files' first event is ta[0]; the epoch ones are rebased to theirs.
    assert out["epoch"]["t"][0] == pytest.approx(out["rel"]["t"][0] - ta[0], abs=1e-6)
    assert len(out["epoch"]["t"]) == len(out["rel"]["t"])
    # Epoch stamps near 1.7e9 s hold only ~2.4e-7 s of resolution, which shifts the share
    # of a report split at a window edge: < 1e-6 here, against 1e-2 if b were misplaced.
    for k in ("x", "y", "theta", "used"):
        np.testing.assert_allclose(out["epoch"][k], out["rel"][k], rtol=0, atol=1e-6, err_msg=k)
    # And b really started later: windows before 1.25 s after a's start use one mouse's
    # motion only, so the pose turns (a moves, b is still).
    assert abs(out["rel"]["theta"][out["rel"]["t"] < 1.2][-1]) > 1e-3


def test_mixed_epoch_and_relative_captures_give_one_duration_replayed_or_converted(tmp_path):
    """The summary's duration compared each capture's own stamps: an epoch file's
    (~1.7e9 s) against a relative one's (from 0), a span of 1.7e9 s where the windows saw
    5 s, while the same captures converted first (one rebased file) gave 5 s.  Both now
    give the span on the replay's time base: a's epoch stamps less its first, b's kept."""
    t = np.arange(1, 201) * 0.01  # 0.01 .. 2.00 s, one report each
    d = np.ones(200, dtype=int)
    a, b = tmp_path / "a.evemu", tmp_path / "b.evemu"
    a.write_text(format_evemu(1.7e9 + t, d, -d, version=None))  # epoch: rebased to 0 .. 1.99
    b.write_text(format_evemu(3.0 + t, -d, d))  # relative: kept at 3.01 .. 5.00
    cfg = tmp_path / "r.yaml"
    cfg.write_text(
        "rate_hz: 100\nmice:\n  a: {cpi: 400, mount: {x: 0, y: 0.1}}\n"
        "  b: {cpi: 400, mount: {x: 0, y: -0.1}}\n"
    )
    caps = ["--capture", f"a={a}", "--capture", f"b={b}"]
    native = tmp_path / "ab.mdcap"
    _ok(run_mousedom("convert", *caps, "-o", str(native)))

    def duration(*capture_args: str) -> float:
        proc = _ok(run_mousedom("replay", "--config", str(cfg), *capture_args))
        line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("duration"))
        return float(line.split()[1])

    direct = duration(*caps)
    converted = duration("--capture", str(native))  # its devices name their mice
    # a's first report to b's last: 5.00 - 0 s (stamps rounded to the microsecond, and an
    # epoch one near 1.7e9 s holds only ~2.4e-7 s).
    assert direct == pytest.approx(5.0 - 0.0, abs=2e-3)
    assert converted == pytest.approx(direct, abs=2e-3)


def test_a_long_pause_is_closed_in_bounded_batches_with_the_same_poses(tmp_path):
    """A rig parked for a while: the tracker closed every window of the pause in one
    batch (a 1e5 s pause at 20 Hz took 1.5 GB).  The engine now hands it out in batches
    of at most MAX_WINDOWS, and the poses equal one batch through the tracker."""
    from mousedom.capture.replay import MAX_WINDOWS
    from mousedom.fusion.tracker import Tracker

    rng = np.random.default_rng(5)
    n = 400
    # Three and more batches' worth of empty windows at 1 kHz, shorter than a gap that
    # replay skips (MAX_GAP_S).
    gap = 3.0 * MAX_WINDOWS / 1000.0

    def times(pause_at):
        t = 0.0037 + np.cumsum(rng.uniform(0.004, 0.02, n))
        t[pause_at:] += gap
        return np.round(t, 6)  # as evemu writes them

    data = {
        "a": (times(150), rng.integers(-4, 5, n), rng.integers(-9, 2, n)),
        "b": (times(150) + 0.001, rng.integers(-4, 5, n), rng.integers(-9, 2, n)),
    }
    data["b"][0][300:] += 2.0  # b pauses once more, for 2 s
    specs = []
    for name, (t, dx, dy) in data.items():
        p = tmp_path / f"{name}.evemu"
        p.write_text(format_evemu(t, dx, dy))
        specs.append((name, str(p)))
    cfg = tmp_path / "r.yaml"
    cfg.write_text(
        "rate_hz: 1000\nmodel: lsq\nmice:\n  a: {cpi: 400, mount: {x: 0.05, y: 0.1}}\n"
        "  b: {cpi: 400, mount: {x: -0.05, y: -0.1}}\n"
    )
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    rp = Replay(config, assign(config, specs))
    sizes, batches = [], []
    summary = rp.run(lambda b: (sizes.append(len(b)), batches.append(b)))
    assert max(sizes) <= MAX_WINDOWS and sum(sizes) > 3 * MAX_WINDOWS
    got = type(batches[0]).concat(batches)

    # The reference: the reports as read (a frame without motion is no report), all at once.
    reports, _, _ = read_reports(config, specs)
    ref = Tracker(config, t0=min(r.t[0] for r in reports.values()))
    for name, r in reports.items():
        ref.push(name, r.t, r.dx, r.dy)
    want = ref.finish()
    assert len(got) == len(want) == summary.windows
    for k in ("t", "x", "y", "theta"):
        np.testing.assert_allclose(getattr(got, k), getattr(want, k), rtol=0, atol=1e-12)
    want_counts = [[data[m][1].sum(), data[m][2].sum()] for m in ("a", "b")]
    np.testing.assert_allclose(got.counts.sum(axis=0), want_counts, rtol=0, atol=1e-6)


def test_summary_path_starts_at_the_origin_and_counts_one_mouse_as_a_mouse(tmp_path):
    """Issue 14 item 7: the path length was measured from the first window's pose, so a
    straight run could have a path shorter than its displacement; and '1 mice'."""
    from mousedom.capture.replay import Summary
    from mousedom.fusion.posebatch import PoseBatch, PoseRow

    s = Summary(("m",))
    eye = np.eye(3).tolist()
    s.add(PoseBatch.from_rows([
        PoseRow(0.01, 0.3, 0.0, 0.0, 30.0, 0.0, 0.0, eye, 1, True, [[0.0, 0.0]], [[0, 0]],
                (0,), (0,), True, eye),
        PoseRow(0.02, 0.4, 0.0, 0.0, 10.0, 0.0, 0.0, eye, 1, True, [[0.0, 0.0]], [[0, 0]],
                (0,), (0,), True, eye),
    ]))  # fmt: skip
    assert s.path_length == pytest.approx(0.4)  # from (0, 0): not 0.1
    cfg = one_mouse_config(tmp_path)
    p = replay_ps2(cfg)
    assert p.returncode == 0 and "replay: 1 mouse, model" in p.stderr + p.stdout
