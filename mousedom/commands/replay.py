"""``mousedom replay``: run captures through the fusion; CSV, summary, plot.

The contract (other tools rely on it)::

    mousedom replay --config RIG.yaml --capture NAME=FILE [--capture NAME=FILE ...]
                    [-o OUT.csv|-] [--model M] [--integrator I] [--plot OUT.png] [--speed X]
"""

from __future__ import annotations

import math
import os
import stat
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO, cast

from mousedom.allocator import keep_freed_memory
from mousedom.angles import wrap_degrees
from mousedom.capture.assignment import assign, captures_of, input_files, parse_capture_arg
from mousedom.capture.posecsv import CsvSink
from mousedom.capture.replay import Replay
from mousedom.capture.summary import Summary
from mousedom.commands import _options as options
from mousedom.commands._replay_health import (
    gyro_line,
    health_lines,
    scale_warning,
    scale_warnings,
    why_line,
)
from mousedom.config import INTEGRATORS, MODELS, Config, load_config
from mousedom.errors import UserError, escaped
from mousedom.fusion.tracker import PoseBatch
from mousedom.plainnumber import plain_float
from mousedom.safewrite import open_stream, refuse_shared_outputs, same_file

# The summary's health lines live in _replay_health; their names stay reachable from here.
__all__ = ["check", "format_summary", "health_lines", "register", "run", "scale_warning",
           "scale_warnings", "why_line"]  # fmt: skip

if TYPE_CHECKING:
    from mousedom.plot import PlotCollector
    from mousedom.service.mcapout import McapRecorder


# --speed: a second of capture takes 1000 s at the slowest (below, the waits overflowed
# the clock: a traceback at 2e-12) and a microsecond at the fastest.
MIN_SPEED, MAX_SPEED = 1e-3, 1e6


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "replay",
        help="replay captures through the fusion (CSV of poses, or a summary)",
        description="Replay evemu, libinput record or native captures through the fusion "
        "engine.  Without -o a summary is printed.",
    )
    options.add_config(p, required=True)
    p.add_argument(
        "--capture",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="a capture for mouse NAME (repeat per mouse); a multi-device file may be given "
        "without NAME= and is matched to the config's mice",
    )
    options.add_output(p, "write the poses as CSV ('-': stdout)")
    p.add_argument("--model", choices=MODELS, help="override the config's model")
    p.add_argument("--integrator", choices=INTEGRATORS, help="override the config's integrator")
    p.add_argument(
        "--no-robust",
        action="store_true",
        help="plain least squares: no fault test, no mouse left out (as `robust: false`; "
        "for comparison)",
    )
    p.add_argument("--plot", metavar="OUT.png", help="draw trajectory and residuals (matplotlib)")
    p.add_argument(
        "--mcap",
        metavar="OUT.mcap",
        help="write the poses as a ROS 2 MCAP recording: /odom, /tf, each mouse's counts "
        "(Foxglove, ros2 bag; needs mousedom[ros2])",
    )
    p.add_argument(
        "--speed",
        type=options.number,
        metavar="X",
        help="pace output at X times real time (default: as fast as possible)",
    )
    p.add_argument(
        "--umbmark",
        choices=("cw", "ccw"),
        help="the run was a UMBmark square in this direction: emit its RUNS.csv row "
        "(odometry end position minus the true one)",
    )
    p.add_argument(
        "--true-end",
        metavar="X,Y",
        default="0,0",
        help="with --umbmark: the measured true end position in the odometry frame, "
        "metres (default 0,0: the square returns to its start)",
    )
    p.add_argument(
        "--umbmark-csv",
        metavar="RUNS.csv",
        help="with --umbmark: append the row to this file (created with its header; an "
        "existing one must be a RUNS.csv `mousedom umbmark` reads, with the columns "
        "direction,dx,dy in that order); default: print the row on stdout",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    keep_freed_memory()  # streams whole captures: see mousedom.allocator
    true_end = _check_args(args)
    config = _load_config(args)
    specs = [parse_capture_arg(a) for a in args.capture]
    if not specs and not any(m.replay for m in config.mice):
        raise UserError(
            f"{args.config}: nothing to replay: give --capture NAME=FILE (or replay: in the config)"
        )
    assignments = assign(config, specs)
    captures = captures_of(assignments)  # the mice's, and a gyro's file of its own
    inputs = input_files(args.config, config.calibration, [c.path for c in captures])
    _check_outputs(args, inputs)
    replay = Replay(config, assignments, model=args.model, integrator=args.integrator)
    sinks = _Sinks.open(args, replay.config, inputs)  # (without a gyro no capture holds)
    sink: Callable[[PoseBatch], None] = sinks
    if args.speed:
        from mousedom.capture.pacing import Pacer, paced

        out = sinks.out
        sink = paced(sink, Pacer(args.speed), flush=out.flush if out is not None else None)

    # Time-base warnings are known before reading: say them now, not after a long replay
    # (files days apart run through every empty window between them).
    early = list(replay.warnings)
    for w in early:
        print(f"mousedom: warning: {w}", file=sys.stderr, flush=True)
    bar = ProgressBar(sys.stderr) if sys.stderr.isatty() and not args.speed else None
    try:
        summary = replay.run(sink, progress=bar.update if bar else None)
    finally:
        if bar:
            bar.close()
        sinks.close()

    for w in summary.warnings[len(early) :]:
        print(f"mousedom: warning: {w}", file=sys.stderr)
    _report(args, config, replay, summary, sinks, true_end, inputs)
    return check(summary)


def _check_args(args) -> tuple[float, float] | None:
    """Refuse contradicting or impossible options before anything is read; the true end
    of a UMBmark run (None without --umbmark)."""
    true_end = _true_end(args) if args.umbmark else None
    if args.umbmark and args.output == "-" and not args.umbmark_csv:
        # Both would go to stdout: the RUNS.csv row would become the pose CSV's last row.
        raise UserError("--umbmark with -o -: give --umbmark-csv RUNS.csv (stdout holds the poses)")
    if args.speed is not None and not (MIN_SPEED <= args.speed <= MAX_SPEED):  # (NaN too)
        raise UserError(f"--speed: must be from {MIN_SPEED:g} to {MAX_SPEED:g}, got {args.speed}")
    if args.plot:
        from mousedom import plot

        plot.require()
    if args.mcap:
        from mousedom.service import mcapout

        mcapout.require()
    return true_end


def _load_config(args) -> Config:
    """The rig config, with --no-robust applied and a --model override checked."""
    config = load_config(args.config, need_sources=False)
    if args.no_robust:
        import dataclasses

        from mousedom.config import RobustConfig

        config = dataclasses.replace(config, robust=RobustConfig(enabled=False))
    if args.model:
        # The config checks its own model against its mice; an override must pass too
        # (lsq on one mouse solved no window and ended at 0,0,0 with exit 0).
        from mousedom.fusion.geometry import rank_problem

        mounts = [(m.mount.x, m.mount.y) for m in config.mice]
        problem = rank_problem(args.model, mounts, config.names)
        if problem:
            raise UserError(f"--model {args.model}: {problem} (in {args.config})")
    return config


class _Sinks:
    """Where the pose batches go: the CSV (-o), the MCAP recording, the plot's collector;
    called with each batch, it hands it to each of them."""

    def __init__(self) -> None:
        self.out: _Output | None = None
        self.recorder: McapRecorder | None = None
        self.collector: PlotCollector | None = None
        self.each: list[Callable[[PoseBatch], None]] = []

    @classmethod
    def open(cls, args, config: Config, inputs: list[str]) -> _Sinks:
        sinks = cls()
        if args.output == "-":
            sinks.out = _Output(sys.stdout, "<stdout>")
        elif args.output:
            # A text stream: open_stream opens text when asked (text=True).
            f = cast(TextIO, open_stream(args.output, inputs, text=True))
            sinks.out = _Output(f, args.output)
        if sinks.out is not None:
            sinks.each.append(CsvSink(sinks.out, config.names, gyro=config.gyro is not None))
        if args.mcap:
            from mousedom.config import Ros2Config
            from mousedom.service.mcapout import McapRecorder

            # stamps: the capture's own clock (a replay has no other)
            sinks.recorder = McapRecorder(args.mcap, config.ros2 or Ros2Config(), config.names,
                                          config.rate_hz, inputs)  # fmt: skip
            sinks.each.append(sinks.recorder.batch)
        if args.plot:
            from mousedom.plot import PlotCollector

            sinks.collector = PlotCollector()
            sinks.each.append(sinks.collector)
        return sinks

    def __call__(self, b: PoseBatch) -> None:
        for s in self.each:
            s(b)

    def close(self) -> None:
        """Finish the CSV and the recording (their last rows written, or the error)."""
        if self.out is not None:
            self.out.finish()
        if self.recorder is not None:
            self.recorder.close()


def _report(
    args,
    config: Config,
    replay: Replay,
    summary: Summary,
    sinks: _Sinks,
    true_end: tuple[float, float] | None,
    inputs: list[str],
) -> None:
    """After the replay: where the files went, the plot, the UMBmark row or the summary."""
    if args.output and args.output != "-":
        _wrote("the poses (CSV)", args.output)
    if args.mcap:
        _wrote("the MCAP recording", args.mcap)
    if sinks.collector is not None:
        from mousedom import plot

        rates = {m.name: m.reports_per_s for m in summary.mice}
        plot.save(sinks.collector, config.names, args.plot, title=_title(args, replay),
                  model=args.model or config.model, rates=rates, inputs=inputs)  # fmt: skip
        _wrote("the plot", args.plot)
    if sinks.out is not None or args.umbmark:  # no summary: its warnings on their own
        for w in scale_warnings(summary, _cpis(config)):
            print(f"mousedom: warning: {w}", file=sys.stderr)
    if true_end is not None:  # --umbmark
        _emit_umbmark(args, summary, true_end, inputs)
    elif sinks.out is None:
        summary_out = _Output(sys.stdout, "<stdout>")
        summary_out.write(format_summary(summary, replay, args) + "\n")
        summary_out.flush()


def _wrote(what: str, path: str) -> None:
    """Where a file went, one line on stderr, the path as given (issue 29 item 6)."""
    print(f"replay: wrote {what} to {path}", file=sys.stderr)


def _check_outputs(args, inputs: list[str]) -> None:
    """Before anything is read or written: no output names an input (-o would truncate it
    before it is read; any would destroy it), and no two outputs name one file (the later
    would replace the earlier, which would still be reported written).  A device such as
    /dev/null may take several."""
    outputs = [
        ("-o", args.output), ("--plot", args.plot), ("--mcap", args.mcap),
        ("--umbmark-csv", args.umbmark_csv if args.umbmark else None),
    ]  # fmt: skip
    for flag, out in outputs:
        if not out or out == "-":
            continue
        for path in inputs:
            if same_file(out, path):
                raise UserError(f"{flag} {out}: that is an input ({path}); it would be overwritten")
    refuse_shared_outputs(outputs)


class _Output:
    """The CSV destination: a write error (disk full, I/O error) is one line naming it.

    A closed pipe (``| head``) stays a BrokenPipeError: the CLI exits quietly on it.
    """

    def __init__(self, f: TextIO, name: str) -> None:
        self.f, self.name = f, name

    def _failed(self, e: OSError) -> UserError:
        return UserError(f"{self.name}: cannot write: {e.strerror or e}")

    def write(self, text: str) -> int:
        try:
            return self.f.write(text)
        except BrokenPipeError:
            raise
        except OSError as e:
            raise self._failed(e) from None

    def flush(self) -> None:
        try:
            self.f.flush()
        except BrokenPipeError:
            raise
        except OSError as e:
            raise self._failed(e) from None

    def finish(self) -> None:
        """Flush (stdout) or close (a file); a failure here would lose the last rows."""
        try:
            if self.f is sys.stdout:
                self.f.flush()
            else:
                self.f.close()
        except BrokenPipeError:
            raise
        except OSError as e:
            if self.f is not sys.stdout:
                try:  # the buffer is gone either way; do not fail again at exit
                    self.f.close()
                except OSError:
                    pass
            raise self._failed(e) from None


def _true_end(args) -> tuple[float, float]:
    try:
        x, y = (plain_float(v) for v in args.true_end.split(","))
    except ValueError:
        raise UserError(f"--true-end: expected X,Y in metres, got {args.true_end!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise UserError(f"--true-end: expected finite numbers, got {args.true_end!r}")
    return x, y


def _emit_umbmark(args, summary: Summary, true_end: tuple[float, float], inputs: list[str]) -> None:
    """One row of `mousedom umbmark`'s RUNS.csv for this run."""
    from mousedom.calibrate.umbmark import umbmark_row

    if not summary.final:
        raise UserError("--umbmark: the captures hold no motion, so there is no end position")
    final = (summary.final["x"], summary.final["y"])
    doubt = _check_direction(args.umbmark, summary.final["theta"])
    row = umbmark_row(args.umbmark, final, true_end)
    if not args.umbmark_csv:
        print(row)
    else:
        try:
            with open_stream(args.umbmark_csv, inputs, append=True, text=True) as f:
                f.write(_runs_lead(f.fileno(), args.umbmark_csv) + row + "\n")
        except OSError as e:
            raise UserError(f"{args.umbmark_csv}: cannot append: {e.strerror}") from None
        print(f"replay: appended {row} to {args.umbmark_csv}", file=sys.stderr)
    if doubt:  # (said of a row written: a refusal is the one line an error is)
        print(f"replay: warning: {doubt}", file=sys.stderr)


def _check_direction(direction: str, turned: float) -> str | None:
    """A UMBmark square turns a full turn, clockwise (-360 degrees) or not: the replay's
    heading (from 0, unwrapped) says which, and a row under the other direction's label
    would score it in the wrong centre of gravity without a word.  Refused; a run that
    turned less than half a turn either way is no square: the doubt returned, to be said
    once the row is written."""
    deg = math.degrees(turned)
    said = {"cw": -1.0, "ccw": 1.0}[direction]
    if abs(deg) >= 180.0 and math.copysign(1.0, deg) != said:
        other = "ccw" if direction == "cw" else "cw"
        raise UserError(
            f"--umbmark {direction}: the run turned {deg:+.0f} degrees, "
            f"{'counter-clockwise' if deg > 0 else 'clockwise'}: it is a {other} run "
            "(no row written)"
        )
    if abs(deg) < 180.0:
        return (f"--umbmark {direction}: the run turned {deg:+.0f} degrees in all, where a "
                "UMBmark square turns 360: is it a whole square?")  # fmt: skip
    return None


def _runs_lead(fd: int, path: str) -> str:
    """What goes before a row appended to the RUNS.csv open (for appending) on ``fd``: the
    header in an empty file (or a pipe), a newline where the last line lacks one; a file
    that `mousedom umbmark` would not read, or whose columns are not the row's, is
    refused (UserError) before anything is written: appending would bury its runs."""
    from mousedom.calibrate.csvtext import content_lines, header_names
    from mousedom.calibrate.umbmark import HEADER, MAX_RUNS_BYTES, parse_runs

    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_size == 0:
        return HEADER + "\n"
    if st.st_size > MAX_RUNS_BYTES:
        raise UserError(f"{path}: {st.st_size} bytes is no RUNS.csv; not appending to it")
    # the file open here, read again through its descriptor: no path in between to swap
    with open(f"/proc/self/fd/{fd}", "rb") as r:
        raw = r.read(MAX_RUNS_BYTES)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise UserError(f"{path}: byte offset {e.start}: not UTF-8 text; not appending") from None
    parse_runs(text, path)  # (its errors name the line: the file is left as it is)
    head_no, head = content_lines(text)[0]  # (parse_runs refused a file without one)
    names = header_names(head, path, head_no)
    if names != HEADER.split(","):
        raise UserError(
            f"{path}: its header has the columns {','.join(names)}; a row of {HEADER} "
            "cannot join it (not appending)"
        )
    return "" if text.endswith("\n") else "\n"


def _counts(c) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in c) + ")"


def _differ(got, want) -> bool:
    """Count pairs that differ by more than float rounding (the tracker sums floats)."""
    return any(abs(a - b) > 1e-6 * max(1.0, abs(b)) for a, b in zip(got, want, strict=True))


def check(summary: Summary) -> int:
    """Every count read must be in the output; anything else is a bug worth an exit code."""
    for m in summary.mice:
        net = (m.stats.net_x, m.stats.net_y)
        if _differ(m.counts_in, net):
            print(
                f"mousedom: error: mouse {m.name}: counts read {_counts(net)} but the fusion "
                f"took {_counts(m.counts_in)}",
                file=sys.stderr,
            )
            return 1
        if _differ(m.counts_out, m.counts_in):
            print(
                f"mousedom: error: mouse {m.name}: {_counts(m.counts_in)} counts in but "
                f"{_counts(m.counts_out)} in the poses",
                file=sys.stderr,
            )
            return 1
    return 0


def _model_integrator(args, replay: Replay) -> tuple[str, str]:
    """What the replay ran with: the command line's overrides, else the config's."""
    return args.model or replay.config.model, args.integrator or replay.config.integrator


def _title(args, replay: Replay) -> str:
    model, integrator = _model_integrator(args, replay)
    return f"{args.config}: model {model}, integrator {integrator}"


def format_summary(s: Summary, replay: Replay, args) -> str:
    cfg = replay.config
    model, integrator = _model_integrator(args, replay)
    lines = [
        f"replay: {len(s.mice)} {'mouse' if len(s.mice) == 1 else 'mice'}, model {model}, "
        f"integrator {integrator}, "
        f"{cfg.rate_hz:g} Hz windows",
        f"duration     {s.duration:.3f} s ({s.reports} reports, {s.windows} windows"
        + (f", {s.not_ok} without enough mice to solve" if s.not_ok else "")
        + ")",
        f"path length  {s.path_length:.4f} m",
    ]
    if s.final:
        f = s.final
        lines.append(
            f"final pose   x {f['x']:+.4f} m  y {f['y']:+.4f} m  theta {f['theta']:+.4f} rad "
            f"(heading {wrap_degrees(f['theta']):+.2f} deg)  at t {f['t']:.3f} s"
        )
    else:
        lines.append("final pose   none (no motion in the captures)")
    lines.append("")
    lines.append(
        f"{'mouse':<12} {'reports':>8} {'rate Hz':>8} {'net x':>8} {'net y':>8} "
        f"{'path x':>8} {'path y':>8} {'skipped':>8} {'dropped':>8}  file (device)"
    )
    for m in s.mice:
        st = m.stats
        # The device's name is the capture's (an evemu N: line, a libinput name: key): a
        # control character in it would reach the terminal raw, ESC as a sequence.
        lines.append(
            f"{m.name:<12} {st.reports:>8} {m.reports_per_s:>8.1f} {st.net_x:>8} {st.net_y:>8} "
            f"{st.path_x:>8} {st.path_y:>8} {st.skipped:>8} {st.dropped_frames:>8}  "
            f"{escaped(m.file)} ({escaped(m.device)})"
        )
        extra = []
        if st.lost_x or st.lost_y:
            extra.append(f"{st.lost_x} x / {st.lost_y} y counts lost in dropped frames")
        if st.unterminated:
            extra.append(f"{st.unterminated} events without SYN_REPORT at the end (kept)")
        if st.torn_bytes:
            extra.append(f"{st.torn_bytes} bytes of torn tail skipped")
        if extra:
            lines.append(" " * 13 + "; ".join(extra))
    gyro = gyro_line(s)
    if gyro:
        lines.append(gyro)
    lines.append("")
    lines += health_lines(s, _cpis(cfg))
    return "\n".join(lines)


def _cpis(cfg) -> dict[str, tuple[float, float]]:
    return {m.name: (m.cpi_x, m.cpi_y) for m in cfg.mice}


class ProgressBar:
    """A one-line bar on a terminal, redrawn at most ten times a second."""

    def __init__(self, out: TextIO, width: int = 40) -> None:
        self.out, self.width = out, width
        self.t0 = time.monotonic()
        self.last = 0.0
        self.drawn = False

    def update(self, fraction: float) -> None:
        now = time.monotonic()
        if self.drawn and now - self.last < 0.1:
            return
        self.last = now
        fraction = min(max(fraction, 0.0), 1.0)
        done = int(self.width * fraction)
        bar = "#" * done + "-" * (self.width - done)
        self.out.write(f"\rreplay [{bar}] {100 * fraction:5.1f}%")
        self.out.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.out.write("\r" + " " * (self.width + 20) + "\r")
            self.out.flush()
