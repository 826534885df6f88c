"""Replay throughput (native and evemu) and peak memory of a long four-mouse capture.

    .venv/bin/python bench/replay.py [--minutes 60] [--evemu-seconds 60] [--repeat 5]

(defaults shown: the issue's one hour is the default run; it takes about 20 s)

Generates, in a temporary directory, a simulated rig of four mice at 1 kHz driving arcs
for ``--minutes`` (60 = the issue's one hour, 14.4 M reports), as one native capture and
(for ``--evemu-seconds``) as four evemu files.  Prints:

- end-to-end replay (read, fuse, write CSV) in reports/s, median of ``--repeat`` rounds
  (in each round the peer, native, evemu, floor and no-CSV runs take turns, and the
  ratios are medians of the per-round ratios),
  from native and from evemu, in this process;
- baselines measured in the same run: the readers alone (no fusion), and evemu parsed by
  the line-by-line fallback parser instead of the vectorised one (ratio = speed-up);
- the peak RSS (VmHWM) and wall time of ``mousedom replay`` of the whole long capture in
  a child process; compare ``--minutes 2`` with ``--minutes 60`` to see memory bounded.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from mousedom.allocator import keep_freed_memory  # noqa: E402
from mousedom.capture import DeviceInfo, NativeWriter, assign, open_capture  # noqa: E402
from mousedom.capture import evemu as evemu_mod  # noqa: E402  (its _fast_events is swapped)
from mousedom.capture.evemu import format_evemu  # noqa: E402
from mousedom.capture.libinput import format_libinput  # noqa: E402
from mousedom.capture.replay import CsvSink, Replay  # noqa: E402
from mousedom.config import parse_config  # noqa: E402
from mousedom.fusion import sim  # noqa: E402

NAMES = ("fl", "fr", "rl", "rr")
PIECE = 60.0  # seconds simulated at a time (bounded memory while generating)


def rig() -> sim.Rig:
    mice = tuple(
        sim.SimMouse(name, x, y, cpi_x=1000.0, cpi_y=1000.0, report_hz=1000.0, phase=k * 1.3e-4)
        for k, (name, x, y) in enumerate(
            zip(NAMES, (0.1, 0.1, -0.1, -0.1), (0.1, -0.1, 0.1, -0.1), strict=True)
        )
    )
    return sim.Rig(mice, rate_hz=100.0)


def piece(k: int) -> list[sim.Segment]:
    # Always moving (so every 1 kHz slot reports), alternating left and right arcs.
    sign = 1 if k % 2 == 0 else -1
    return sim.arc(sign * 1.5, PIECE * 0.2 / 1.5, speed=0.2)


def generate(directory: Path, minutes: float, evemu_seconds: float) -> tuple[Path, list[Path], int]:
    r = rig()
    cfg = directory / "rig.yaml"
    cfg.write_text(sim.rig_yaml(r))
    native = directory / "long.mdcap"
    devices = [DeviceInfo(name=f"sim {n}", mouse=n, rel_xy=True) for n in NAMES]
    total = 0
    evemu_parts: dict[str, list] = {n: [] for n in NAMES}
    with NativeWriter(native, devices, time_base="relative", config_text=cfg.read_text()) as w:
        pieces = max(1, math.ceil(minutes * 60.0 / PIECE))
        for k in range(pieces):
            res = sim.simulate(r, piece(k), seed=k, t_start=k * PIECE)
            end = (k + 1) * PIECE
            for i, n in enumerate(NAMES):
                rep = res.reports[n]
                keep = rep.t < end  # pieces must not overlap
                t, dx, dy = rep.t[keep], rep.dx[keep], rep.dy[keep]
                w.motion(i, t, dx.astype(np.int64), dy.astype(np.int64))
                total += len(t)
                if k * PIECE < evemu_seconds:
                    lim = t < evemu_seconds
                    evemu_parts[n].append((t[lim], dx[lim], dy[lim]))
            w.sync(np.nextafter(end, -np.inf))
    evemu_files = []
    devices_li = []
    for n in NAMES:
        t = np.concatenate([p[0] for p in evemu_parts[n]])
        dx = np.concatenate([p[1] for p in evemu_parts[n]]).astype(np.int64)
        dy = np.concatenate([p[2] for p in evemu_parts[n]]).astype(np.int64)
        path = directory / f"{n}.evemu"
        path.write_text(format_evemu(t, dx, dy, name=f"sim {n}", comments=True))
        evemu_files.append(path)
        devices_li.append((n, t, dx, dy))
    (directory / "all.yml").write_text(format_libinput(devices_li))
    return cfg, evemu_files, total


def replay_once(cfg: Path, specs: list[tuple[str | None, str]]) -> tuple[float, int]:
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    t0 = time.perf_counter()
    rp = Replay(config, assign(config, specs))
    with open(os.devnull, "w") as out:
        summary = rp.run(CsvSink(out))
    return time.perf_counter() - t0, summary.reports


def read_only(specs: list[tuple[str | None, str]]) -> tuple[float, int]:
    t0 = time.perf_counter()
    n = 0
    for _, path in specs:
        cap = open_capture(path)
        for feed in cap.feeds():
            for batch in feed.batches:
                n += sum(len(m.t) for m in batch.motion)
    return time.perf_counter() - t0, n


def peer_loop(cfg: Path, files: list[Path]) -> tuple[float, int]:
    """What a user would write without mousedom: read each evemu file line by line, sum
    REL_X/REL_Y into 10 ms buckets by event time, solve each bucket's least squares with
    numpy and write a CSV row."""
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    t0 = time.perf_counter()
    n = len(files)
    rate = config.rate_hz
    a = np.zeros((2 * n, 3))
    scale = []
    for i, m in enumerate(config.mice):
        a[2 * i] = (1, 0, -m.mount.y)
        a[2 * i + 1] = (0, 1, m.mount.x)
        scale.append(0.0254 / m.cpi_x)
    buckets: dict[int, np.ndarray] = {}
    reports = 0
    for i, path in enumerate(files):
        with open(path) as f:
            for line in f:
                if not line.startswith("E:"):
                    continue
                parts = line.split()
                if parts[2] == "0002":
                    k = int(float(parts[1]) * rate)
                    w = buckets.get(k)
                    if w is None:
                        w = buckets[k] = np.zeros((n, 2))
                    w[i, int(parts[3], 16)] += int(parts[4])
                elif parts[2] == "0000":
                    reports += 1
    pose = np.zeros(3)
    with open(os.devnull, "w") as out:
        out.write("t,x,y,theta\n")
        for k in sorted(buckets):
            c = buckets[k]
            # evdev: REL_X right, REL_Y back -> body forward = -REL_Y, left = -REL_X
            d = np.stack([-c[:, 1], -c[:, 0]], axis=1) * np.array(scale)[:, None]
            q = np.linalg.lstsq(a, d.reshape(-1), rcond=None)[0]
            ct, st = math.cos(pose[2]), math.sin(pose[2])
            pose += (ct * q[0] - st * q[1], st * q[0] + ct * q[1], q[2])
            out.write(f"{(k + 1) / rate:.6f},{pose[0]:.9f},{pose[1]:.9f},{pose[2]:.9f}\n")
    return time.perf_counter() - t0, reports


def vectorised_floor(cfg: Path, specs: list[tuple[str | None, str]]) -> tuple[float, int]:
    """The least an in-process replay can cost: the capture read, then one pass of numpy
    over all of it: each mouse's count function at every window edge (the tracker's
    rule: a report covers [max(previous, t - P), t]), lsq on the same windows with the
    same estimator, exact integration; no covariance, no health, no CSV."""
    from mousedom.fusion import integrate, models
    from mousedom.fusion.units import counts_matrices, sigma_metres

    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    t0 = time.perf_counter()
    per_mouse = {m.name: ([], [], []) for m in config.mice}
    n = 0
    for name, path in specs:
        cap = open_capture(path)
        for feed in cap.feeds():
            for batch in feed.batches:
                for mo in batch.motion:
                    who = name or cap.devices[mo.device].mouse
                    for col, v in zip(per_mouse[who], (mo.t, mo.dx, mo.dy), strict=True):
                        col.append(v)
                    n += len(mo.t)
    cols = {k: [np.concatenate(c) for c in v] for k, v in per_mouse.items()}
    start = min(c[0][0] for c in cols.values())
    end = max(c[0][-1] for c in cols.values())
    period = 1.0 / config.rate_hz
    edges = start + period * np.arange(int((end - start) / period) + 2)
    counts = np.empty((len(edges) - 1, len(config.mice), 2))
    for i, m in enumerate(config.mice):
        t, dx, dy = cols[m.name]
        span_start = np.maximum(np.concatenate([[t[0] - 1.0 / m.report_hz], t[:-1]]),
                                t - 1.0 / m.report_hz)  # fmt: skip
        knot_t = np.stack([span_start, t], axis=1).reshape(-1)
        for k, c in enumerate((dx, dy)):
            cum = np.cumsum(c)
            knot_c = np.stack([cum - c, cum], axis=1).reshape(-1)
            counts[:, i, k] = np.diff(np.interp(edges, knot_t, knot_c))
    d = np.einsum("nij,knj->kni", counts_matrices(config.mice), counts)
    pos = np.array([[m.mount.x, m.mount.y] for m in config.mice])
    sigma = np.array([sigma_metres(m) for m in config.mice])
    live = np.ones(len(config.mice), dtype=bool)
    _, b, _ = models.estimator(pos.tobytes(), sigma.tobytes(), live.tobytes(), (0, 1, 2))
    q = d.reshape(len(d), -1) @ b.T
    poses = integrate.compose(np.zeros(3), integrate.body_step(q, "exact"))
    assert np.isfinite(poses).all()
    return time.perf_counter() - t0, n


def quiet_replay(cfg: Path, specs: list[tuple[str | None, str]]) -> tuple[float, int]:
    """replay_once without the CSV: what the fusion itself costs next to the floor."""
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    t0 = time.perf_counter()
    summary = Replay(config, assign(config, specs)).run(lambda b: None)
    return time.perf_counter() - t0, summary.reports


def interleaved(runs: dict, counts: dict[str, int]) -> dict[str, float]:
    """One round: each run once, in turn; reports/s by name (``counts`` gets the number
    of reports of each)."""
    out = {}
    for name, fn in runs.items():
        dt, counts[name] = fn()
        out[name] = counts[name] / dt
    return out


def median_rate(fn, repeat: int) -> tuple[float, int]:
    rates, n = [], 0
    for _ in range(repeat):
        dt, n = fn()
        rates.append(n / dt)
    return statistics.median(rates), n


# The child reports its own high-water mark (VmHWM of its address space).  ru_maxrss from
# wait4 would also count the pages it shared with this (large) parent before exec.
CHILD = """
import sys
from mousedom.cli import main
try:
    code = main(sys.argv[1:])
finally:
    hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")]
    print("CHILD-" + hwm[0].strip(), file=sys.stderr)
raise SystemExit(code)
"""


def child_replay(cfg: Path, native: Path, csv: Path) -> tuple[float, float, int]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    cmd = [sys.executable, "-c", CHILD, "replay", "--config", str(cfg)]
    cmd += ["--capture", str(native), "-o", str(csv)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"child replay failed: {proc.stderr}")
    hwm = next(ln for ln in proc.stderr.splitlines() if ln.startswith("CHILD-VmHWM"))
    rss_mb = int(hwm.split()[1]) / 1024.0  # kB
    rows = sum(1 for _ in open(csv)) - 1
    return wall, rss_mb, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="long capture length (1 h)")
    ap.add_argument("--evemu-seconds", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    # As `mousedom replay` does (mousedom.allocator): every run in this process, the
    # baselines too, reuses freed memory instead of faulting in fresh pages.
    print(f"malloc keeps freed memory (as mousedom replay): {keep_freed_memory()}")
    with tempfile.TemporaryDirectory(prefix="mousedom-bench-") as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        cfg, evemu_files, total = generate(d, args.minutes, args.evemu_seconds)
        native = d / "long.mdcap"
        print(
            f"generated {total} reports ({args.minutes:g} min, 4 mice, 1 kHz) in "
            f"{time.perf_counter() - t0:.1f} s; native {native.stat().st_size / 1e6:.1f} MB, "
            f"evemu {sum(p.stat().st_size for p in evemu_files) / 1e6:.1f} MB "
            f"({args.evemu_seconds:g} s)"
        )

        # In-process throughput on the first minute's worth of native data (same as evemu).
        short = d / "short.mdcap"
        from mousedom.commands.convert import convert

        caps = [(n, open_capture(p)) for n, p in zip(NAMES, map(str, evemu_files), strict=True)]
        convert(caps, str(short))
        native_specs = [(None, str(short))]
        evemu_specs = list(zip(NAMES, map(str, evemu_files), strict=True))

        libinput_specs = [(None, str(d / "all.yml"))]
        # The runs the ratios are made of take turns, round by round, so that each ratio
        # compares runs made within a second of each other on this shared machine: the
        # ratios are the medians of the per-round ratios.
        runs = {
            "peer": lambda: peer_loop(cfg, evemu_files),
            "native": lambda: replay_once(cfg, native_specs),
            "evemu": lambda: replay_once(cfg, evemu_specs),
            "floor": lambda: vectorised_floor(cfg, native_specs),
            "quiet": lambda: quiet_replay(cfg, native_specs),
        }
        counts: dict[str, int] = {}
        rounds = [interleaved(runs, counts) for _ in range(args.repeat)]
        rate = {k: statistics.median(r[k] for r in rounds) for k in runs}
        nat, ev, peer, floor, quiet = (
            rate[k] for k in ("native", "evemu", "peer", "floor", "quiet")
        )
        n_nat, n_ev = counts["native"], counts["evemu"]

        def ratio(a: str, b: str) -> float:
            return statistics.median(r[a] / r[b] for r in rounds)

        li, n_li = median_rate(lambda: replay_once(cfg, libinput_specs), args.repeat)
        nat_read, _ = median_rate(lambda: read_only(native_specs), args.repeat)
        ev_read, _ = median_rate(lambda: read_only(evemu_specs), args.repeat)
        fast = evemu_mod._fast_events
        evemu_mod._fast_events = lambda block, line: None  # force the line-by-line parser
        try:
            ev_slow, _ = median_rate(lambda: read_only(evemu_specs), 1)
        finally:
            evemu_mod._fast_events = fast
        print(f"{args.repeat} rounds, each running the peer, native, evemu, floor and "
              "no-CSV replays in turn; rates and ratios are medians over the rounds "
              "(line-by-line parser: 1 run)")  # fmt: skip
        print(f"peer-style loop, evemu text   : {peer:12,.0f} reports/s (per line, 10 ms "
              "buckets, numpy lstsq per window, CSV)")  # fmt: skip
        print(f"native replay / peer          : {ratio('native', 'peer'):8.1f}x (target >= 20)")
        print(f"evemu replay / peer           : {ratio('evemu', 'peer'):8.1f}x (target >= 5)")
        print(f"vectorised floor, native      : {floor:12,.0f} reports/s (read, count "
              "functions, lsq, exact steps; no covariance, no CSV)")  # fmt: skip
        print(f"native replay without CSV     : {quiet:12,.0f} reports/s: "
              f"{ratio('floor', 'quiet'):.2f}x the floor's time (target <= 1.5)")  # fmt: skip
        print(f"replay end to end, native : {nat:12,.0f} reports/s  ({n_nat} reports)")
        print(f"replay end to end, evemu  : {ev:12,.0f} reports/s  ({n_ev} reports)")
        print(f"replay end to end, libinput record: {li:12,.0f} reports/s  ({n_li} reports)")
        print(
            f"baseline, native read only: {nat_read:12,.0f} reports/s  (fusion+CSV costs "
            f"{nat_read / nat:.2f}x)"
        )
        print(
            f"baseline, evemu read only : {ev_read:12,.0f} reports/s  (fusion+CSV costs "
            f"{ev_read / ev:.2f}x)"
        )
        print(
            f"baseline, evemu line by line parser: {ev_slow:12,.0f} reports/s  "
            f"(vectorised parser is {ev_read / ev_slow:.1f}x faster)"
        )

        wall, rss, rows = child_replay(cfg, native, d / "long.csv")
        print(
            f"long capture: mousedom replay of {total} reports in {wall:.1f} s "
            f"({total / wall:,.0f} reports/s incl. start-up), {rows} CSV rows, "
            f"peak RSS {rss:.0f} MB"
        )


if __name__ == "__main__":
    main()
