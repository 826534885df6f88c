"""Regenerate the bundled demo: mousedom/data/demo-rig.yaml and demo-rig.mdcap.

A simulated three-mouse rig (mousedom.fusion.sim.three_mouse_rig: 800 CPI, 125 Hz, mice on a
triangle round the body origin) drives Borenstein's UMBmark square (1 m sides,
counter-clockwise), with a little sensor noise, and is written as a native capture with
the rig config in its header.  ``mousedom run --demo`` replays it in real time, looping;
``mousedom replay --config mousedom/data/demo-rig.yaml`` replays it at once.

    /work/venv/bin/python scripts/make_demo.py [--out mousedom/data]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from mousedom.capture import DeviceInfo, NativeWriter  # noqa: E402
from mousedom.fusion import sim  # noqa: E402

NAME = "demo-rig"
STEP = 0.5  # seconds of data per sync point


def rig_yaml(rig: sim.Rig, capture: str) -> str:
    lines = [
        "# The bundled demo rig: three simulated mice on a triangle of radius 0.15 m.",
        "# Made by scripts/make_demo.py; `mousedom run --demo` replays it in a loop.",
        f"rate_hz: {rig.rate_hz!r}",
        f"model: {rig.model}",
        f"integrator: {rig.integrator}",
        "mice:",
    ]
    for m in rig.mice:
        lines += [
            f"  {m.name}:",
            f"    cpi: {{x: {m.cpi_x!r}, y: {m.cpi_y!r}}}",
            f"    mount: {{x: {round(m.x, 9)!r}, y: {round(m.y, 9)!r}, yaw: {m.yaw!r}}}",
            f"    report_hz: {m.report_hz!r}",
            "    sigma: 1.0",
            f"    replay: {capture}",
        ]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(REPO / "mousedom" / "data"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = sim.three_mouse_rig(cpi=800.0, report_hz=125.0)
    rig = replace(base, mice=tuple(replace(m, noise=0.3) for m in base.mice), rate_hz=50.0)
    traj = sim.umbmark_square(cw=False, side=1.0, speed=0.25, turn_rate=0.8, rest=0.5)
    res = sim.simulate(rig, traj, seed=2026)
    capture = out / f"{NAME}.mdcap"
    config = out / f"{NAME}.yaml"
    config.write_text(rig_yaml(rig, capture.name))
    devices = [
        DeviceInfo(name=f"simulated mouse {m.name}", mouse=m.name, rel_xy=True, bus=0x03)
        for m in rig.mice
    ]
    end = float(res.motion.starts[-1])
    with NativeWriter(
        capture,
        devices,
        config_text=config.read_text(),
        time_base="relative",
        meta={"first_time": 0.0, "source": "scripts/make_demo.py (mousedom.fusion.sim)"},
    ) as w:
        k = 0
        while k * STEP <= end + 1.0:
            lo, hi = k * STEP, (k + 1) * STEP
            for i, m in enumerate(rig.mice):
                r = res.reports[m.name]
                sel = (r.t >= lo) & (r.t < hi)
                w.motion(i, r.t[sel], r.dx[sel].astype(np.int64), r.dy[sel].astype(np.int64))
            w.sync(float(np.nextafter(hi, -np.inf)))
            k += 1
    truth = res.truth(end)[0]
    print(
        f"{config} and {capture}: {res.total_reports()} reports, {end:.1f} s, "
        f"{capture.stat().st_size} bytes; true final pose "
        f"({truth[0]:.4f}, {truth[1]:.4f}, {truth[2]:.4f})"
    )


if __name__ == "__main__":
    main()
