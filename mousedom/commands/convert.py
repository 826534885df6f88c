"""``mousedom convert``: evemu / libinput record / native captures -> one native capture.

    mousedom convert --capture NAME=FILE [--capture NAME=FILE ...] -o OUT.mdcap
                     [--config RIG.yaml] [--no-compress]

NAME becomes the device's mouse name in the native header, so the result replays with
``--capture OUT.mdcap`` alone.  Inputs are merged by time in bounded memory.  A native
input's gyro (an "iio" device) is kept with its samples, exactly; only the native format
holds a gyro (evemu and libinput record describe input devices, not IIO sensors).
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from typing import Any, BinaryIO, cast

from mousedom import saferead
from mousedom.allocator import keep_freed_memory
from mousedom.capture.assignment import input_files, parse_capture_arg
from mousedom.capture.base import (
    GYRO_KIND,
    TIME_BASES,
    Capture,
    CaptureError,
    DeviceInfo,
    Feed,
    lagging_first,
)
from mousedom.capture.native_writer import NativeWriter
from mousedom.capture.sniff import open_capture
from mousedom.capture.timebase import grid_anchor, time_offset
from mousedom.commands import _options as options
from mousedom.errors import UserError
from mousedom.safewrite import open_stream, replace_file, same_file


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "convert",
        help="convert evemu / libinput record captures into one native capture",
        description="Merge captures (evemu, libinput record, native) into one mousedom "
        "native capture (see docs/captures.md); a native input's gyro is kept (only the "
        "native format holds one).",
    )
    p.add_argument(
        "--capture",
        action="append",
        default=[],
        required=True,
        metavar="NAME=FILE",
        help="an input; NAME (optional) is the config mouse its device stands for",
    )
    options.add_output(p, "the native capture to write ('-': stdout)", required=True)
    options.add_config(p, "store this rig config in the capture's header")
    p.add_argument("--no-compress", action="store_true", help="store chunks uncompressed")
    p.set_defaults(func=run)


def run(args) -> int:
    keep_freed_memory()  # streams whole captures: see mousedom.allocator
    config_text = None
    calibration = None
    if args.config:
        from mousedom.config import load_config

        # (refused early if broken; its calibration is an input no output may name)
        calibration = load_config(args.config, need_sources=False).calibration
        config_text = saferead.read_text(args.config)
    inputs: list[tuple[str | None, Capture]] = []
    for arg in args.capture:
        name, path = parse_capture_arg(arg)
        inputs.append((name, open_capture(path)))
    paths = input_files(args.config, calibration, [cap.path for _, cap in inputs])
    for path in paths:
        if path and same_file(args.output, path):
            raise UserError(f"{args.output}: the output would overwrite an input ({path})")
    if args.output == "-":
        # As replay's -o -: the capture goes to stdout (a pipe, e.g. to ssh or gzip).
        options.binary_stdout()  # (refused early where it cannot be a pipe)
        try:
            stats = convert(
                inputs, sys.stdout.buffer, config_text=config_text, compress=not args.no_compress
            )
        except BrokenPipeError:
            # Not `| head` having read enough: the capture is the product, and the reader
            # has a cut one (exit 0 here, as the CLI gives a reader that went away, hid it
            # from pipefail).  Nothing more to stdout, not even Python's flush at exit.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            raise UserError(
                "<stdout>: the reader went away; the capture it got is cut short", exit_code=1
            ) from None
        except OSError as e:
            raise UserError(f"<stdout>: cannot write: {e.strerror or e}") from None
        size = None
    else:
        stats = _convert_into(args.output, inputs, config_text, not args.no_compress, paths)
        size = os.path.getsize(args.output)
    for w in stats["warnings"]:
        print(f"mousedom: warning: {w}", file=sys.stderr)
    print(
        f"{args.output}: {stats['devices']} devices"
        + (f" ({stats['gyros']} gyro)" if stats["gyros"] else "")
        + f", {stats['reports']} reports"
        + (f", {stats['samples']} gyro samples" if stats["gyros"] else "")
        + (f", {size} bytes" if size is not None else ""),
        file=sys.stderr,  # where it wrote, with the rest of the status (issue 29 item 6)
    )
    return 0


def _convert_into(
    output: str,
    inputs: list[tuple[str | None, Capture]],
    config_text: str | None,
    compress: bool,
    protect: list[str],
) -> dict[str, Any]:
    """Convert into a fresh temporary file beside ``output`` and rename it on success.

    An input found bad half-way (or a full disk) must not leave a short capture behind
    that replays without a word, nor clobber an older ``output``; the temporary file's
    name is unpredictable and made with O_EXCL (safewrite), so a planted link cannot
    redirect it.  A pipe or device (/dev/stdout, a FIFO) is written in place.
    """
    stats: dict[str, Any] = {}

    def write(target: str) -> None:
        stats.update(convert(inputs, target, config_text=config_text, compress=compress))
        read_back(target, output, stats["written"])

    if os.path.exists(output) and not os.path.isfile(output):
        try:
            with open_stream(output, protect) as f:
                out = cast(BinaryIO, f)  # binary: open_stream opens text only when asked
                stats.update(convert(inputs, out, config_text=config_text, compress=compress))
        except OSError as e:  # also from the close's last flush
            raise UserError(f"{output}: cannot write: {e.strerror or e}") from None
        return stats
    replace_file(output, write, protect)
    return stats


@dataclass
class _Input:
    """One feed being merged: its devices' indices in the output, its time shift."""

    feed: Feed
    out: dict[int, int]  # device in the capture -> device in the output
    sub: float  # seconds subtracted (epoch files rebased)
    capture: Capture
    watermark: float = -math.inf  # everything before it has been written
    done: bool = False


def convert(
    inputs: list[tuple[str | None, Capture]],
    path: str | os.PathLike[str] | BinaryIO,
    *,
    config_text: str | None = None,
    compress: bool = True,
) -> dict[str, Any]:
    """Write the motion devices of ``inputs`` into one native capture at ``path``."""
    captures = [c for _, c in inputs]
    time_base, offset, warnings = _time_base(captures)
    devices, states = _gather(inputs, offset)
    _refuse_a_mouse_twice(devices)
    _refuse_a_file_twice(inputs)
    written = [[0, 0, 0] for _ in devices]  # per output device: reports, net x, net y
    # The inputs' first event (not first report) anchors the replay's window grid and the
    # epoch rebasing: keep it, so that replaying the result gives the very same poses.
    meta = {"first_time": _first_time(captures, offset)}
    if len(captures) == 1:
        # One native capture converted (recompressed, or to a file): what it says of how it
        # was made goes with it, the rig's config snapshot unless -c gives another
        (one,) = captures
        if config_text is None:
            config_text = getattr(one, "config_text", None)
        meta.update({k: one.header[k] for k in ("recorder", "config_path") if k in one.header})
    if any(c.grid_start() is not None for c in captures):
        # (a daemon's recording: replay anchors its windows where the daemon's began)
        meta["grid_start"] = grid_anchor(captures, offset)
    with NativeWriter(
        path,
        devices,
        config_text=config_text,
        time_base=time_base,
        compress=compress,
        meta=meta,
    ) as w:
        reports, samples = _copy(w, states, written)
        for s in states:
            for dev, out_dev in s.out.items():
                w.note(out_dev, s.capture.stats[dev])
        w.sync(math.inf)
    for _, cap in inputs:
        warnings += cap.warnings
    gyros = sum(d.kind == GYRO_KIND for d in devices)
    return {"devices": len(devices), "reports": reports, "warnings": warnings, "written": written,
            "gyros": gyros, "samples": samples}  # fmt: skip


def _time_base(captures: list[Capture]) -> tuple[str, float, list[str]]:
    """The output's time base, the seconds subtracted from epoch inputs, and warnings:
    one base in, the times kept exactly as recorded; mixed, epoch files rebased."""
    bases = {c.time_base for c in captures}
    offset, warnings = time_offset(captures)
    if len(bases) == 1:
        time_base, offset = bases.pop(), 0.0  # keep the times exactly as recorded
    else:
        time_base = "relative"  # epoch files rebased; the others kept
    assert time_base in TIME_BASES
    return time_base, offset, warnings


def _gather(
    inputs: list[tuple[str | None, Capture]], offset: float
) -> tuple[list[DeviceInfo], list[_Input]]:
    """The output's devices (each input's motion devices and gyro, in order) and the feeds
    that carry them."""
    devices: list[DeviceInfo] = []
    states: list[_Input] = []
    for name, cap in inputs:
        movers = [i for i, d in enumerate(cap.devices)
                  if d.rel_xy is not False and d.kind != GYRO_KIND]  # fmt: skip
        gyros = [i for i, d in enumerate(cap.devices) if d.kind == GYRO_KIND]
        if not movers and not gyros:
            raise CaptureError(f"{cap.path}: no device with REL_X/REL_Y motion")
        if name is not None and len(movers) > 1:
            raise CaptureError(
                f"--capture {name}={cap.path}: the file holds {len(movers)} motion devices; "
                "give it without NAME= (device names are kept)"
            )
        sub = offset if cap.time_base == "epoch" else 0.0
        index = {}
        for i in sorted(movers + gyros):
            d = cap.devices[i]
            mouse = name if name is not None and i in movers else d.mouse
            info = DeviceInfo(**{**d.as_dict(), "mouse": mouse})
            info.extra = {**d.extra, "converted_from": os.path.basename(cap.path)}
            index[i] = len(devices)
            devices.append(info)
        for feed in cap.feeds():
            mine = {d: index[d] for d in feed.devices if d in index}
            if mine:
                states.append(_Input(feed, mine, sub, cap))
    return devices, states


def _refuse_a_file_twice(inputs: list[tuple[str | None, Capture]]) -> None:
    """One file (by device and inode: a link, another name, the other half of an evemu
    pair) given twice is written twice, every report doubled, unless each time names a
    different mouse (``--capture a=F --capture b=F``: two mice, as in replay)."""
    for k, (name, cap) in enumerate(inputs):
        for other_name, other in inputs[:k]:
            if not same_file(cap.path, other.path):
                continue
            if name is None or other_name is None or name == other_name:
                given = [f"{n}={c.path}" if n is not None else c.path
                         for n, c in ((other_name, other), (name, cap))]  # fmt: skip
                raise CaptureError(
                    f"--capture {given[1]}: the same file as --capture {given[0]}; every "
                    "report would be written twice: give it once (or with a different "
                    "mouse name each time, --capture a=FILE --capture b=FILE)"
                )


def _refuse_a_mouse_twice(devices: list[DeviceInfo]) -> None:
    seen: dict[str, DeviceInfo] = {}
    for d in devices:
        if d.mouse is not None and d.mouse in seen:
            raise CaptureError(
                f"mouse {d.mouse!r} would be recorded twice: device {seen[d.mouse].name!r} of "
                f"{seen[d.mouse].extra['converted_from']} and device {d.name!r} of "
                f"{d.extra['converted_from']} (the result could not be replayed)"
            )
        if d.mouse is not None:
            seen[d.mouse] = d


def _first_time(captures: list[Capture], offset: float) -> float | None:
    """The inputs' first event, on the output's time base."""
    firsts = [
        t - (offset if c.time_base == "epoch" else 0.0)
        for c in captures
        if (t := c.first_time()) is not None
    ]
    return min(firsts) if firsts else None


def _copy(w: NativeWriter, states: list[_Input], written: list[list[int]]) -> tuple[int, int]:
    """Merge the feeds by time into ``w``, a sync point wherever every feed has reached
    one; tally what each output device got in ``written``; the reports and gyro samples
    written."""
    reports = samples = 0
    synced = -math.inf
    for st, batch in lagging_first(states):
        if batch is None:
            continue
        for mo in batch.motion:
            if mo.device in st.out and len(mo.t):
                t = mo.t - st.sub if st.sub else mo.t
                w.motion(st.out[mo.device], t, mo.dx, mo.dy)
                reports += len(mo.t)
                tally = written[st.out[mo.device]]
                tally[0] += len(mo.t)
                tally[1] += int(mo.dx.sum())
                tally[2] += int(mo.dy.sum())
        for chunk in batch.serial:  # raw ADNS-3080 bytes are kept as they are
            if chunk.device in st.out:
                w.serial_many(st.out[chunk.device], (chunk.t - st.sub).tolist(), chunk.data)
        for rates in batch.gyro:  # a gyro's samples, as they are (times rebased as motion)
            if rates.device in st.out and len(rates.t):
                w.gyro(st.out[rates.device], rates.t - st.sub if st.sub else rates.t, rates.rate,
                       rates.saturated)  # fmt: skip
                samples += len(rates.t)
                written[st.out[rates.device]][0] += len(rates.t)
        if batch.complete > -math.inf:
            st.watermark = batch.complete - st.sub
        marks = [s.watermark for s in states if not s.done]
        mark = min(marks) if marks else math.inf
        if math.isfinite(mark) and mark > synced:
            w.sync(mark)
            synced = mark
    return reports, samples


def read_back(path: str, output: str, written: list[list[int]]) -> None:
    """Read the capture just written and check that it gives back every report and count
    (UserError otherwise, and the output is not kept): a writer must never exit 0 with a
    file its reader refuses or reads differently."""
    try:
        cap = open_capture(path)
        for feed in cap.feeds():
            for _ in feed.batches:
                pass
    except CaptureError as e:
        raise UserError(f"{output}: the capture written does not read back ({e}); "
                        "not kept: please report this") from None  # fmt: skip
    got = [[s.reports, s.net_x, s.net_y] for s in cap.stats]
    if got != written:
        raise UserError(
            f"{output}: the capture written reads back as {got} (reports, net x, net y per "
            f"device), not {written}; not kept: please report this"
        )
