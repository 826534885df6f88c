"""`mousedom calibrate cpi|distance|mounts|scales`: the calibration procedures.

Input is either captures (``--capture NAME=FILE``, runs split at idle gaps) or the live
mice of the config (Enter starts and stops each run); ``scales`` replays a drive's
captures through the fusion and reads each mouse's learnt scale.  The readable report goes to
stdout, or with ``--json`` to stderr while stdout carries only the JSON.  ``--write``
merges the result into the calibration file the config references.  The work is in
``mousedom.calibrate``; this is argument handling and I/O.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Any

from mousedom.allocator import keep_freed_memory
from mousedom.calibrate import calfile, report, scales, session
from mousedom.calibrate.inputs import load_captures
from mousedom.calibrate.reference import WheelGeometry, read_reference
from mousedom.calibrate.runs import check_whole_captures, need_runs, split_runs
from mousedom.capture.assignment import config_captures, input_files, parse_capture_arg
from mousedom.commands import _options as options
from mousedom.config import Config, load_config
from mousedom.errors import UserError
from mousedom.plainnumber import plain_float, plain_int
from mousedom.safewrite import refuse_inputs


def _argument(convert, ok, requirement: str, kind: str = "number"):
    """An argparse type: ``convert`` the text, then check ``ok``; messages say what is
    wanted (argparse prefixes them with the option's name)."""

    def parse(text: str):
        try:
            v = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a {kind}: {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"must be {requirement}, got {text}")
        return v

    return parse


_positive = _argument(plain_float, lambda v: v > 0 and math.isfinite(v), "a positive number")
# Lengths a rig can have (a push, a wheel, a track): past these the arithmetic overflows
# (1e300 m) or divides by nothing (1e-300 m) and prints inf.
_length = _argument(plain_float, lambda v: 1e-4 <= v <= 1e7, "a length between 0.0001 and 1e7 m")
_angle = _argument(plain_float, lambda v: 0.1 <= abs(v) <= 36000, "between 0.1 and 36000 degrees")
_ticks = _argument(plain_float, lambda v: 1 <= v <= 1e9, "between 1 and 1e9 ticks")
_count = _argument(plain_int, lambda v: v >= 1, "1 or more", kind="whole number")
_window = _argument(
    plain_float, lambda v: v >= 0 and math.isfinite(v), "0 (one window per run) or more"
)


def register(sub: argparse._SubParsersAction) -> None:
    common = argparse.ArgumentParser(add_help=False)
    options.add_default_config(common)
    common.add_argument(
        "--capture",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="a recording of mouse NAME (repeatable); without it, live mice",
    )
    common.add_argument(
        "--mouse",
        action="append",
        default=[],
        metavar="NAME",
        help="calibrate only this mouse (repeatable)",
    )
    common.add_argument(
        "--gap",
        type=_positive,
        default=0.5,
        metavar="SECONDS",
        help="idle time that separates runs in captures (default 0.5)",
    )
    common.add_argument(
        "--runs",
        type=_count,
        default=None,
        metavar="N",
        help="live: stop after N runs (default: until q or end of input)",
    )
    common.add_argument(
        "--min-runs",
        type=_count,
        default=None,
        metavar="N",
        help="fewest runs accepted (default 2; mounts 1; a standard error needs 2)",
    )
    common.add_argument("--json", action="store_true", help="print JSON on stdout")
    common.add_argument(
        "--write", action="store_true", help="store the result in the config's calibration file"
    )

    p = sub.add_parser(
        "calibrate",
        help="calibrate CPI, mouse distance, mount positions, or CPI from the other mice",
        description="Calibration procedures of the seed papers, on live mice (Enter starts "
        "and stops each run) or on --capture files, and the CPI of each mouse from the "
        "others' (scales: a recorded drive of three or more mice). Each prints a report; "
        "--json prints JSON; --write stores the result in the config's calibration file.",
    )
    what = p.add_subparsers(dest="what", metavar="WHAT", required=True)

    c = what.add_parser(
        "cpi",
        parents=[common],
        help="CPI from straight pushes (Bonarini 4.2)",
        description="Counts per inch from straight pushes of a known length along one of "
        "the mouse's axes (Bonarini et al. 2004, section 4.2): one run per push.",
    )
    c.add_argument(
        "--distance", type=_length, required=True, metavar="METRES", help="length of each push"
    )
    c.add_argument(
        "--axis",
        choices=("x", "y"),
        default="y",
        help="the mouse's own axis pushed along (y: forward/back, default)",
    )
    c.add_argument("--force", action="store_true", help=FORCE_HELP)
    c.set_defaults(func=run_cpi)

    d = what.add_parser(
        "distance",
        parents=[common],
        help="distance between two mice from turns (Bonarini eqs. 18-19)",
        description="The distance between two mice from turns in place by a known angle "
        "(Bonarini et al. 2004, eqs. 18-19): one run per turn.",
    )
    d.add_argument(
        "--angle",
        type=_angle,
        required=True,
        metavar="DEGREES",
        help="the known angle of each turn",
    )
    d.add_argument("--mice", metavar="A,B", help="the two mice (default: the only two)")
    d.add_argument("--force", action="store_true", help=FORCE_HELP)
    d.set_defaults(func=run_distance)

    m = what.add_parser(
        "mounts",
        parents=[common],
        help="mount positions from a reference motion (Kim & Lee IV)",
        description="Each mouse's mount position, yaw and CPI scale from a reference motion "
        "given as body twist or wheel ticks (Kim & Lee, section IV; the McGill wheel model).",
    )
    m.add_argument(
        "--reference",
        required=True,
        metavar="REF.csv",
        help="t,vx,vy,omega (body twist) or t,left,right (wheel ticks)",
    )
    m.add_argument(
        "--method",
        choices=("exact", "kimlee"),
        default="exact",
        help="exact: position, yaw and CPI scale per mouse (default); kimlee: Kim & Lee's "
        "linearised positions, as published",
    )
    m.add_argument(
        "--window",
        type=_window,
        default=0.25,
        metavar="SECONDS",
        help="window length inside runs (0: one window per run; default 0.25)",
    )
    wheels = "for a t,left,right reference (or the config's wheels: section)"
    m.add_argument("--wheel-radius", type=_length, metavar="METRES", help=f"wheel radius, {wheels}")
    m.add_argument(
        "--ticks-per-rev", type=_ticks, metavar="TICKS", help=f"encoder ticks per turn, {wheels}"
    )
    m.add_argument(
        "--track", type=_length, metavar="METRES", help=f"distance between the wheels, {wheels}"
    )
    m.add_argument("--force", action="store_true", help=FORCE_HELP)
    m.set_defaults(func=run_mounts)

    sc = what.add_parser(
        "scales",
        help="each mouse's CPI from the others (the online scale, three or more mice)",
        description="Replay the captures of a drive through the fusion (as `mousedom "
        "replay` does, fault handling and scale learning on) and print each mouse's learnt "
        "scale: the factor its counts need to agree with the other mice, its standard "
        "deviation, and the CPI that implies (the configured CPI divided by the scale). "
        "Needs three or more mice; refuses scales known less well than --max-spread. The "
        "scales are relative: a CPI error common to all the mice cannot be seen "
        "(docs/calibration.md). --write stores the corrected CPI of each mouse whose scale "
        "is plain (beyond three standard deviations and 0.5 % from 1).",
    )
    options.add_default_config(sc)
    sc.add_argument(
        "--capture",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="a recording of mouse NAME (repeatable; every mouse of the config needs one, "
        "or its replay: entry); a multi-device file may be given without NAME=",
    )
    sc.add_argument(
        "--max-spread",
        type=_argument(plain_float, lambda v: 0 < v <= 100, "a percentage between 0 and 100"),
        default=100 * scales.MAX_SPREAD,
        metavar="PERCENT",
        help=f"the largest standard deviation of a scale accepted, in per cent (default "
        f"{100 * scales.MAX_SPREAD:g})",
    )
    sc.add_argument("--json", action="store_true", help="print JSON on stdout")
    sc.add_argument(
        "--write",
        action="store_true",
        help="store the corrected CPIs in the config's calibration file",
    )
    sc.set_defaults(func=run_scales)


# --------------------------------------------------------------------------- shared steps


def _check_write_target(args: argparse.Namespace, config: Config) -> None:
    """Before any work: ``--write`` needs a calibration file, and it may not be a file the
    command reads (a capture given or replayed, its evemu pair, a reference), which the
    result would replace."""
    if not args.write:
        return
    if not config.calibration:
        raise UserError(
            f"{args.config}: --write needs a calibration file: add a line such as "
            "`calibration: rig.calib.yaml` to the config"
        )
    captures = [path for _, path in map(parse_capture_arg, args.capture or [])]
    reads = input_files(config.path, None, captures + config_captures(config))
    reference = getattr(args, "reference", None)
    refuse_inputs(config.calibration, [*reads, reference])


def _setup(args: argparse.Namespace, names: list[str] | None = None):
    keep_freed_memory()  # streams whole captures: see mousedom.allocator
    # Only what calibration uses is checked: no model needs to be solvable (one mouse on a
    # jig is a rig for CPI), and CPI needs no mount.
    cpi_only = args.func is run_cpi
    config = load_config(
        args.config, need_sources=False, need_model=False, need_mounts=not cpi_only
    )
    replaying = args.capture or any(m.replay for m in config.mice)
    _check_write_target(args, config)
    wanted = names or args.mouse
    for n in wanted:
        if n not in config.names:
            raise UserError(f"{args.config}: no mouse {n!r} (it has {', '.join(config.names)})")
    if replaying:
        recording, warnings = load_captures(args.capture, config)
        for w in warnings:  # before a long calibration, as replay says it before replaying
            print(f"mousedom: warning: {w}", file=sys.stderr)
        if wanted:
            missing = [n for n in wanted if n not in recording]
            if missing:
                raise UserError(f"no --capture for mouse {', '.join(missing)}")
            recording = {n: recording[n] for n in wanted}
        runs = split_runs(recording, args.gap)
        check_whole_captures(recording, runs, args.gap)
    else:
        recording, runs = _live(config, wanted or list(config.names), args)
    return config, session.make_session(config, recording, runs)


def _live(config: Config, names: list[str], args: argparse.Namespace):
    from mousedom.calibrate.live import collect_runs
    from mousedom.sources.evdev import EvdevSource

    sources = []
    for n in names:
        m = config.mouse(n)
        if m.evdev is None:
            raise UserError(
                f"mouse {n}: live calibration reads evdev mice; record this one "
                "with `mousedom record` and give it with --capture"
            )
        sources.append(EvdevSource(m))
    what = {"cpi": "push", "distance": "turn"}.get(args.what, "run")
    stdin = sys.stdin.fileno() if sys.stdin is not None else -1  # (None: closed, <&-)
    return collect_runs(sources, stdin, sys.stderr, args.runs, what)


def _emit(
    args: argparse.Namespace, doc: dict, lines: list[str], s: session.Session, warnings: list[str]
) -> None:
    bad = _not_finite(doc)
    if bad is not None:
        raise UserError(
            f"the result is not a finite number ({bad}): the runs or the arguments "
            "(--distance, --angle) cannot give a calibration"
        )
    text_out = sys.stderr if args.json else sys.stdout
    try:
        for line in lines:
            print(line, file=text_out)
        for note in s.notes:
            print(f"note: {note}", file=sys.stderr)
        for w in warnings:
            print(f"mousedom: warning: {w}", file=sys.stderr)
        if args.json:
            print(json.dumps(doc, indent=2))
        sys.stdout.flush()
    except BrokenPipeError:
        # stdout's reader went (`--write | head`): the report is lost, the calibration is
        # not: --write goes on (it was lost with exit 0 before), and stdout is discarded
        # from here, so that nothing fails again at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        print("mousedom: warning: stdout's reader went away: the report was not shown",
              file=sys.stderr)  # fmt: skip


def _not_finite(doc: Any, path: str = "") -> str | None:
    """The JSON path of the first non-finite number in a result, or None."""
    if isinstance(doc, float) and not math.isfinite(doc):
        return f"{path or 'value'} = {doc}"
    if isinstance(doc, dict):
        items: Any = doc.items()
    elif isinstance(doc, (list, tuple)):
        items = enumerate(doc)
    else:
        return None
    for k, v in items:
        found = _not_finite(v, f"{path}.{k}" if path else str(k))
        if found:
            return found
    return None


FORCE_HELP = (
    "with --write: store the result even though its runs disagree or it gives a CPI no "
    "mouse reports"
)


def _refuse_doubtful(config: Config, warnings: list[str], force: bool) -> None:
    """Runs that disagree (or mice that slipped apart), or a CPI outside what mice report
    (``plausible.cpi_problem``: bad runs, or hostile data), make a result no one should
    trust: said, and not stored unless --force.  A result merely far from the configured
    value is stored with its warning: the configured value may be the rough guess."""
    if warnings and not force:
        raise UserError(
            f"{config.calibration}: not written: the runs disagree or the result is not "
            "what a mouse reports (warnings above); repeat them, or pass --force to store "
            "the result anyway"
        )


# --------------------------------------------------------------------------- subcommands


def run_cpi(args: argparse.Namespace) -> int:
    config, s = _setup(args)
    min_runs = args.min_runs or 2
    need_runs(len(s.runs), min_runs, "calibrate cpi", args.gap)
    results = session.cpi(s, args.distance, args.axis, min_runs)
    warnings = [f"mouse {n}: {w}" for n, r in results.items() for w in r.warnings]
    hints = [f"mouse {n}: {w}" for n, r in results.items() for w in r.hints]
    doc = {n: r.as_json() for n, r in results.items()}
    _emit(args, doc, report.cpi_text(results, config, args.distance), s, warnings + hints)
    if args.write:
        _refuse_doubtful(config, warnings, args.force)

        def update(data):
            for n, r in results.items():
                m = config.mouse(n)  # the other axis as it stands (calibration applied)
                cpi = {"x": m.cpi_x, "y": m.cpi_y, args.axis: round(r.cpi, 3)}
                data = calfile.merge_mouse(data, n, cpi=cpi)
            return data

        calfile.store(config, update)
    return 0


def run_distance(args: argparse.Namespace) -> int:
    pair = None
    if args.mice:
        pair = [p.strip() for p in args.mice.split(",")]
        if len(pair) != 2 or not all(pair):
            raise UserError(f"--mice {args.mice!r}: give two mouse names, e.g. --mice left,right")
        if pair[0] == pair[1]:
            raise UserError(f"--mice {args.mice!r}: names one mouse twice: give two mice")
    config, s = _setup(args, pair)
    if len(s.names) != 2:  # said before anything about runs, which would not help
        raise UserError(
            f"{args.config}: calibrate distance takes exactly two mice, and {len(s.names)} have "
            f"data ({', '.join(s.names)}; the config has {', '.join(config.names)}): "
            "choose two with --mice A,B"
        )
    min_runs = args.min_runs or 2
    need_runs(len(s.runs), min_runs, "calibrate distance", args.gap)
    result = session.distance(s, math.radians(args.angle), min_runs)
    _emit(
        args,
        result.as_json(),
        report.distance_text(result, s.names, args.angle),
        s,
        result.warnings + result.hints,
    )
    if args.write:
        _refuse_doubtful(config, result.warnings, args.force)
        positions = session.spread_mounts(config, s.names, result.distance)

        def update(data):
            for n, (x, y) in positions.items():
                data = calfile.merge_mouse(data, n, mount={"x": round(x, 6), "y": round(y, 6)})
            return calfile.merge_section(data, "distance", {"mice": s.names, **result.as_json()})

        calfile.store(config, update)
    return 0


def _wheel_geometry(args: argparse.Namespace, config: Config) -> WheelGeometry | None:
    given = [args.wheel_radius, args.ticks_per_rev, args.track]
    if all(v is not None for v in given):
        return WheelGeometry(args.wheel_radius, args.wheel_radius, args.track, args.ticks_per_rev)
    if any(v is not None for v in given):
        raise UserError("--wheel-radius, --ticks-per-rev and --track go together")
    return config.wheels  # None when the config has no wheels: section


def run_mounts(args: argparse.Namespace) -> int:
    config, s = _setup(args)
    ref = read_reference(args.reference)  # after a live session: the logger may write it
    need_runs(len(s.runs), args.min_runs or 1, "calibrate mounts", args.gap)
    geo = _wheel_geometry(args, config)
    result = session.mounts(s, ref, args.method, geo, args.window, args.gap)
    doubtful = session.implausible_mounts(result, config)
    lines = report.mounts_text(result, config)
    _emit(args, report.mounts_json(result), lines, s, result.warnings + doubtful)
    if args.write:
        _refuse_doubtful(config, doubtful, args.force)

        def update(data):
            for n, f in result.fits.items():
                mount = {"x": round(f.x, 6), "y": round(f.y, 6)}
                values: dict[str, Any] = {"mount": mount}
                if result.method == "exact":
                    m = config.mouse(n)
                    mount["yaw"] = round(math.degrees(f.yaw), 4)
                    values["scale"] = (
                        {"x": round(f.scale_x, 6), "y": round(f.scale_y, 6)}
                        if f.per_axis
                        else round(f.scale, 6)
                    )
                    values["cpi"] = {
                        "x": round(m.cpi_x * f.scale_x, 3),
                        "y": round(m.cpi_y * f.scale_y, 3),
                    }
                data = calfile.merge_mouse(data, n, **values)
            return data

        calfile.store(config, update)
    return 0


def run_scales(args: argparse.Namespace) -> int:
    keep_freed_memory()  # streams whole captures: see mousedom.allocator
    config = load_config(args.config, need_sources=False)
    _check_write_target(args, config)
    result = scales.learn(config, args.capture, max_spread=args.max_spread / 100.0)
    for w in result.warnings:
        print(f"mousedom: warning: {w}", file=sys.stderr)
    scales.check(result, args.max_spread / 100.0)
    text_out = sys.stderr if args.json else sys.stdout
    for line in scales.report_text(result, args.config):
        print(line, file=text_out)
    if args.json:
        print(json.dumps(result.as_json(), indent=2))
    if not args.write:
        return 0
    changed = [m for m in result.mice if m.change]
    if not changed:
        print(f"{config.calibration}: not written: every mouse agrees with the others",
              file=sys.stderr)  # fmt: skip
        return 0

    for m in changed:
        if not m.axes_seen:
            # Stored (the configured ratio of the two CPIs is the best the drive can say),
            # but not silently: a mouse off on one axis only has the other put off too.
            change = 1.0 / m.scale - 1.0
            print(
                f"mousedom: warning: {m.name}: cpi x and y both written {abs(change):.1%} "
                f"{'higher' if change > 0 else 'lower'}: the drive does not tell its two axes "
                "apart, so this assumes both are off alike; if only one is, the other is now "
                "off by as much (`calibrate cpi --axis x` and `--axis y` measure each)",
                file=sys.stderr,
            )

    def update(data):
        for m in changed:
            cx, cy = m.written  # per axis: the implied CPI where that axis changes
            data = calfile.merge_mouse(data, m.name, cpi={"x": cx, "y": cy})
        # informational: what was learnt, against which CPI
        learnt = {}
        for m in result.mice:
            entry: dict[str, Any] = {"scale": round(m.scale, 6), "spread": round(m.spread, 6)}
            if m.per_axis:
                axes = zip("xy", m.scales, m.spreads, strict=True)
                entry["per_axis"] = {
                    a: {"scale": round(g, 6), "spread": round(sd, 6)} for a, g, sd in axes
                }
            entry["cpi_before"] = {"x": m.cpi[0], "y": m.cpi[1]}
            learnt[m.name] = entry
        return calfile.merge_section(data, "scales", learnt)

    calfile.store(config, update)
    return 0
