"""Regenerate the bundled calibration samples: mousedom/data/cal-*.

One simulated three-mouse rig with known truth, and the rough config a builder would start
from (cal-rig.yaml: the drawing's mounts, the datasheet's 800 CPI).  The truth differs
from it as a real rig's does: the front mouse really has 812 CPI, and every mount sits a
millimetre or few off the drawing (TRUTH below).  One session per procedure of
docs/calibration.md, each small and seeded, so that the files come out byte-identical
every time:

- cal-cpi.mdcap: six pushes of 0.2 m, forth and back along the rig's forward axis (the
  mice's own y), with pauses (``calibrate cpi``);
- cal-turns.mdcap: the two side mice, four turns of 90 degrees about a point near their
  middle, alternately left and right (``calibrate distance``);
- cal-drive.mdcap and cal-drive-ref.csv: a drive (straight, turn on the spot, arc, slide,
  reverse) with its body twist as a reference on the same clock (``calibrate mounts``);
- cal-scales.mdcap: a drive of straights, arcs and turns through the fusion's simulator
  (``calibrate scales``);
- cal-umbmark.csv: UMBmark's RUNS.csv from ten simulated 4 m squares, five each way,
  fused with the rough config without the online scale (``mousedom umbmark``);
  cal-umbmark-after.csv: the same drives fused with the true values (what a perfect
  calibration would give).

The sessions of cpi, distance and mounts come from ``mousedom.calibrate.synth`` (exact
counts of a twist that ramps up and down, as the calibration code's own tests use), the
scales drive and the squares from ``mousedom.fusion.sim`` (the general simulator, whose
reports go through the fusion).  Both add sensor noise, so the results are near the
truth, not on it.

    .venv/bin/python scripts/make_calibration_samples.py [--out mousedom/data]
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from mousedom.calibrate.synth import SynthMouse, build_motion, mouse_reports, twist_csv  # noqa: E402
from mousedom.calibrate.umbmark import HEADER, umbmark_row  # noqa: E402
from mousedom.capture import DeviceInfo, NativeWriter  # noqa: E402
from mousedom.config import parse_config  # noqa: E402
from mousedom.fusion import sim  # noqa: E402

PREFIX = "cal-"
CONFIG = "cal-rig.yaml"
# The header's creation time, fixed: a sample made again must be the same bytes.
CREATED = "2026-01-01T00:00:00Z"
REPORT_HZ = 125.0


@dataclass(frozen=True)
class Mount:
    x: float  # metres
    y: float
    cpi: float  # both axes


# What the config says (a drawing and a datasheet) ...
ROUGH = {
    "front": Mount(0.150, 0.0, 800.0),
    "left": Mount(-0.075, 0.130, 800.0),
    "right": Mount(-0.075, -0.130, 800.0),
}
# ... and what the rig really is.  Only the front mouse's CPI is off, so that the distance
# between the side mice (whose CPI is right) is measured without a CPI calibration first.
TRUTH = {
    "front": Mount(0.153, 0.002, 812.0),
    "left": Mount(-0.076, 0.131, 800.0),
    "right": Mount(-0.074, -0.131, 800.0),
}
PUSH_M = 0.2  # calibrate cpi --distance
PUSHES = 6
TURN_DEG = 90.0  # calibrate distance --angle
TURNS = 4
PIVOT = (-0.07, 0.01)  # the point the turns are about (body frame, m)
SIDE_M = 4.0  # UMBmark's square
SQUARES = 5  # per direction


def true_distance() -> float:
    """Metres between the side mice (what calibrate distance measures)."""
    a, b = TRUTH["left"], TRUTH["right"]
    return math.hypot(a.x - b.x, a.y - b.y)


def rig_yaml(mice: dict[str, Mount] = ROUGH) -> str:
    """The config: as first written (ROUGH), or with ``mice`` (TRUTH: as if calibrated)."""
    lines = [
        "# The calibration samples' rig as first configured: the drawing's mounts and the",
        "# datasheet's CPI (docs/calibration.md). Made by scripts/make_calibration_samples.py;",
        "# the captures are cal-*.mdcap beside it. --write stores results in the calibration",
        "# file below (created beside this file): copy the samples somewhere writable first.",
        "rate_hz: 100.0",
        "model: lsq",
        "calibration: cal-rig.calib.yaml",
        "mice:",
    ]
    for name, m in mice.items():
        lines += [
            f"  {name}:",
            f"    cpi: {m.cpi:g}",
            f"    mount: {{x: {m.x:g}, y: {m.y:g}}}",
            f"    report_hz: {REPORT_HZ:g}",
        ]
    return "\n".join(lines) + "\n"


def synth_mice(names: tuple[str, ...], rel_noise: float = 0.01) -> list[SynthMouse]:
    """The true mice, each with its own report phase and a little noise per report."""
    return [
        SynthMouse(
            n, TRUTH[n].x, TRUTH[n].y, cpi_x=TRUTH[n].cpi, cpi_y=TRUTH[n].cpi,
            report_hz=REPORT_HZ, phase=0.3 * i, rel_noise=rel_noise, abs_noise=0.3,
        )
        for i, n in enumerate(names)
    ]  # fmt: skip


def write_capture(path: Path, reports: dict, source: str) -> None:
    """A native capture (relative times: a simulation has no clock) of per-mouse reports,
    each device recorded as its mouse, in half-second chunks as `mousedom record` writes."""
    devices = [DeviceInfo(name=f"simulated mouse {n}", mouse=n, rel_xy=True) for n in reports]
    end = max(float(r.t[-1]) for r in reports.values())
    meta = {"created": CREATED, "first_time": 0.0, "source": source}
    with NativeWriter(path, devices, time_base="relative", meta=meta) as w:
        step, k = 0.5, 0
        while k * step <= end:
            lo, hi = k * step, (k + 1) * step
            for i, r in enumerate(reports.values()):
                sel = (r.t >= lo) & (r.t < hi)
                w.motion(i, r.t[sel], r.dx[sel].astype(np.int64), r.dy[sel].astype(np.int64))
            w.sync(float(np.nextafter(hi, -np.inf)))
            k += 1


def cpi_session(out: Path) -> None:
    # Pushes along body x, which every mouse (yaw 0) sees along its own y axis.
    motion = build_motion([(PUSH_M * (-1) ** k, 0.0, 0.0, 1.4) for k in range(PUSHES)])
    mice = synth_mice(("front", "left", "right"))
    reports = {m.name: mouse_reports(m, motion, seed=10 + i) for i, m in enumerate(mice)}
    write_capture(out / "cal-cpi.mdcap", reports, "cpi pushes (mousedom.calibrate.synth)")


def turns_session(out: Path) -> None:
    eta = math.radians(TURN_DEG)
    px, py = PIVOT
    # A turn by eta about the pivot p moves the body origin by eta * (p_y, -p_x).
    moves = [(eta * py * s, -eta * px * s, eta * s, 2.0) for s in (1, -1) * (TURNS // 2)]
    motion = build_motion(moves)
    mice = synth_mice(("left", "right"))
    reports = {m.name: mouse_reports(m, motion, seed=20 + i) for i, m in enumerate(mice)}
    write_capture(out / "cal-turns.mdcap", reports, "turns (mousedom.calibrate.synth)")


def drive_session(out: Path) -> None:
    # Straight, a turn on the spot, an arc, a slide with a turn, reverse: the motion must
    # separate position from CPI scale (docs/calibration.md, "Mount positions").
    motion = build_motion(
        [(0.3, 0, 0, 2), (0, 0, 1.5, 2), (0.2, 0, 0.8, 2), (0, 0.1, -1, 2), (-0.2, 0, 0, 2)]
    )
    mice = synth_mice(("front", "left", "right"))
    reports = {m.name: mouse_reports(m, motion, seed=30 + i) for i, m in enumerate(mice)}
    write_capture(out / "cal-drive.mdcap", reports, "drive (mousedom.calibrate.synth)")
    # The reference a tracking system would log, at 50 Hz, on the captures' clock.
    (out / "cal-drive-ref.csv").write_text(twist_csv(motion, 50.0))


def sim_rig(noise: float = 0.3) -> sim.Rig:
    """The true rig for mousedom.fusion.sim (yaw 0; phases spread over a report period)."""
    mice = tuple(
        sim.SimMouse(n, m.x, m.y, cpi_x=m.cpi, cpi_y=m.cpi, report_hz=REPORT_HZ,
                     phase=i / (3 * REPORT_HZ), noise=noise)
        for i, (n, m) in enumerate(TRUTH.items())
    )  # fmt: skip
    return sim.Rig(mice, rate_hz=100.0)


def scales_session(out: Path) -> None:
    legs = [sim.pause(0.3), sim.straight(0.3, 0.3)]
    for k in range(4):
        legs += [sim.straight(0.3, 0.3), sim.arc(0.4, math.pi / 4 * (-1) ** k, 0.3),
                 sim.turn(math.pi / 4, 0.8), sim.pause(0.3)]  # fmt: skip
    res = sim.simulate(sim_rig(), sim.sequence(*legs), seed=40)
    reports = {n: res.reports[n] for n in TRUTH}
    write_capture(out / "cal-scales.mdcap", reports, "drive (mousedom.fusion.sim)")


def umbmark_rows(mice: dict[str, Mount], squares: int = SQUARES) -> list[str]:
    """RUNS.csv rows of ``squares`` squares each way, fused with a config that says
    ``mice``: the odometry's end minus the true end (the start: a square closes).  Square k
    of a direction is the same drive (seed) whatever the config and however many are made.

    The online scale is not applied (``learn_scale: false``): it would correct the front
    mouse's CPI as the square goes, and the runs are to show what the calibration alone
    leaves (docs/calibration.md)."""
    text = rig_yaml(mice) + "robust: {learn_scale: false}\n"
    config = parse_config(text, "<cal-rig.yaml>", need_sources=False)
    rows = []
    for d in ("cw", "ccw"):
        for k in range(squares):
            path = sim.umbmark_square(cw=d == "cw", side=SIDE_M, speed=0.5, turn_rate=1.0)
            res = sim.simulate(sim_rig(), path, seed=50 + 10 * (d == "cw") + k)
            batch, _ = sim.run_tracker(res, config)
            final = (float(batch.x[-1]), float(batch.y[-1]))
            rows.append(umbmark_row(d, final, (0.0, 0.0)))
    return rows


def umbmark_runs(out: Path, name: str, mice: dict[str, Mount]) -> None:
    (out / name).write_text("\n".join([HEADER, *umbmark_rows(mice)]) + "\n")


def make(out: Path, umbmark: bool = True) -> list[Path]:
    """Write every sample into ``out``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    (out / CONFIG).write_text(rig_yaml())
    cpi_session(out)
    turns_session(out)
    drive_session(out)
    scales_session(out)
    if umbmark:
        umbmark_runs(out, "cal-umbmark.csv", ROUGH)  # before calibration
        umbmark_runs(out, "cal-umbmark-after.csv", TRUTH)  # after a perfect one
    return sorted(out.glob(f"{PREFIX}*"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(REPO / "mousedom" / "data"), help="directory")
    args = ap.parse_args()
    for p in make(Path(args.out)):
        print(f"{p}: {p.stat().st_size} bytes")
    print(
        f"truth: front cpi {TRUTH['front'].cpi:g} (configured {ROUGH['front'].cpi:g}); "
        f"left - right {true_distance() * 1000:.2f} mm (configured "
        f"{math.hypot(0, ROUGH['left'].y - ROUGH['right'].y) * 1000:.2f} mm)"
    )


if __name__ == "__main__":
    main()
