"""`mousedom umbmark RUNS.csv`: Borenstein & Feng's UMBmark from square runs."""

from __future__ import annotations

import argparse
import json
import sys

from mousedom import saferead
from mousedom.allocator import keep_freed_memory
from mousedom.calibrate import calfile, report
from mousedom.calibrate.umbmark import HEADER, MAX_RUNS_BYTES, parse_runs, umbmark
from mousedom.commands import _options as options
from mousedom.config import load_config
from mousedom.errors import UserError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "umbmark",
        help="systematic odometry error (E_max,syst) from 4 m squares cw and ccw",
        description=f"RUNS.csv: header {HEADER}; one run per line, direction cw or ccw, "
        "odometry end position minus true end position in metres.",
    )
    p.add_argument("runs", metavar="RUNS.csv", help="the runs ('-' for stdin)")
    options.add_config(p, "the rig config whose calibration file --write updates")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.add_argument(
        "--write",
        action="store_true",
        help="store E_max,syst in the config's calibration file, for the record (nothing "
        "reads it back)",
    )
    p.set_defaults(func=run)


def _read(path: str) -> str:
    try:
        # Bytes, decoded here: binary garbage is one clear line whatever the locale.
        raw = (
            sys.stdin.buffer.read(MAX_RUNS_BYTES + 1)
            if path == "-"
            else saferead.read_bytes(path, MAX_RUNS_BYTES)
        )
        if len(raw) > MAX_RUNS_BYTES:  # (/dev/zero on stdin: a MemoryError traceback)
            name = "<stdin>" if path == "-" else path
            raise UserError(f"{name}: more than {MAX_RUNS_BYTES} bytes is no RUNS.csv")
        return raw.decode("utf-8")
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except UnicodeDecodeError as e:
        name = "<stdin>" if path == "-" else path
        raise UserError(f"{name}: byte offset {e.start}: not UTF-8 text") from None
    except OSError as e:
        raise UserError(f"{path}: cannot read: {e.strerror}") from None


def run(args: argparse.Namespace) -> int:
    keep_freed_memory()  # streams whole captures: see mousedom.allocator
    config = None
    if args.write:
        if not args.config:
            raise UserError("--write needs --config (its calibration file holds the result)")
        config = load_config(args.config, need_sources=False)
        if not config.calibration:
            raise UserError(
                f"{args.config}: --write needs a calibration file: add a line "
                "such as `calibration: rig.calib.yaml` to the config"
            )
    name = "<stdin>" if args.runs == "-" else args.runs
    directions, errors = parse_runs(_read(args.runs), name)
    try:
        result = umbmark(directions, errors)
    except ValueError as e:
        raise UserError(f"{name}: {e}") from None
    text_out = sys.stderr if args.json else sys.stdout
    for line in report.umbmark_text(result):
        print(line, file=text_out)
    for w in result.warnings:
        print(f"mousedom: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(result.as_json(), indent=2))
    if config is not None:
        calfile.store(config, lambda data: calfile.merge_section(data, "umbmark", result.as_json()))
    return 0
