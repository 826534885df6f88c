"""What a decompression bomb costs `replay` now: time, peak memory, exit status.

    .venv/bin/python bench/bombs.py [--claim-mib 1000]

Four bombs, each a small file that claims ``--claim-mib`` of data: a native capture whose
zlib chunks hold 64 MiB of zero reports each (about 64 KB stored), and evemu text
compressed with gzip, xz and bzip2 (one compressed block repeated, as ``cat a.gz a.gz``
joins streams).  Each is replayed in a process of its own; its peak RSS is the kernel's
(``getrusage`` of that child), its time the wall clock.  A bomb must be refused (exit 2)
after bounded work: docs/captures.md, "Files as users hand them over".
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from test_bombs import _text_bomb, native_bomb  # noqa: E402  (the suite's bombs)

RIG = (
    "rate_hz: 100\nmodel: diff-drive\nmice:\n  m:\n    cpi: 800\n"
    "    mount: {x: 0.1, y: 0, yaw: 0}\n"
)
MEASURE = (
    "import resource, subprocess, sys, time\n"
    "t = time.monotonic()\n"
    "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
    "dt = time.monotonic() - t\n"
    "rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
    "last = (p.stderr.strip().splitlines() or [''])[-1]\n"
    "print(p.returncode, rss, dt, last.split(': ', 2)[-1])\n"
)


def replay(cfg: Path, capture: Path, out: Path) -> tuple[int, float, float, str]:
    cmd = [sys.executable, "-c", MEASURE, sys.executable, "-m", "mousedom", "replay",
           "--config", str(cfg), "--capture", f"m={capture}", "-o", str(out)]  # fmt: skip
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    line = subprocess.run(cmd, capture_output=True, text=True, env=env).stdout
    code, rss, dt, msg = line.split(" ", 3)
    return int(code), int(rss) / 1024, float(dt), msg.strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--claim-mib", type=int, default=1000, help="what each bomb claims (1000)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mousedom-bombs-") as tmp:
        d = Path(tmp)
        cfg = d / "rig.yaml"
        cfg.write_text(RIG)
        bombs = {"native (zlib chunks)": d / "n.mdcap"}
        native_bomb(bombs["native (zlib chunks)"], chunks=max(1, args.claim_mib // 64))
        for kind, suffix in (("gzip", ".gz"), ("xz", ".xz"), ("bzip2", ".bz2")):
            path = d / f"t.events{suffix}"
            path.write_bytes(_text_bomb(kind, args.claim_mib << 20))
            bombs[f"{kind} evemu text"] = path
        print(f"each bomb claims {args.claim_mib} MiB; replay in its own process")
        print(f"{'bomb':22s} {'file':>9s} {'exit':>4s} {'peak RSS':>9s} {'time':>7s}  message")
        for name, path in bombs.items():
            code, rss, dt, msg = replay(cfg, path, d / "o.csv")
            size = path.stat().st_size / 1e6
            msg = msg.replace(f"{d}/", "")
            print(f"{name:22s} {size:7.2f} MB {code:4d} {rss:6.1f} MB {dt:6.2f} s  {msg[:80]}")


if __name__ == "__main__":
    main()
