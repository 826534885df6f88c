"""What ``mousedom watch`` shows, as text: pure functions of the protocol's messages.

Read cold, a screen must explain itself: the heading is wrapped to (-180, 180] degrees
(the daemon's theta is continuous: +442 deg is the fifth quarter turn), time counts from
when the watch began, every number has its name and unit, the uncertainty is called what
it is (one standard deviation, from the POSE covariance), each sensor's state is a word
(in colour where the terminal has it), its learnt scale a deviation in per cent with the
warning under it when there is one, and the path so far is sketched when it fits.  The
screen fits 80 columns: the sensors are a table under one row of column names, and what
needs words (a reason, an error, a scale warning) goes on lines under its sensor's row,
wrapped to the terminal.
"""

from __future__ import annotations

import math
import re
import textwrap
from typing import Any

from mousedom.angles import wrap_degrees  # the one definition (replay and client use it)

__all__ = ["wrap_degrees", "screen", "pose_lines", "pose_line", "source_table", "sketch"]

GREEN, YELLOW, RED, DIM, RESET = "\x1b[32m", "\x1b[33m", "\x1b[31m", "\x1b[2m", "\x1b[0m"


def _num(v: float | None, fmt: str, scale: float = 1.0) -> str:
    return "n/a" if v is None or not math.isfinite(v) else format(v * scale, fmt)


def pose_lines(m: dict[str, Any], t_start: float) -> list[str]:
    heading = None if m.get("theta") is None else wrap_degrees(m["theta"])
    turn = None if m.get("omega") is None else math.degrees(m["omega"])
    state = "updating" if m["updating"] else "NOT UPDATING (the mice cannot tell the motion)"
    # The frames named: the position is in the odometry frame (where the robot started,
    # x its first forward), the velocity in the robot's own body frame.
    lines = [
        f"position (odom)  x {_num(m['x'], '+9.4f')} m  y {_num(m['y'], '+9.4f')} m  "
        f"heading {_num(heading, '+7.2f')} deg",
        f"velocity (body)  forward {_num(m['vx'], '+7.3f')} m/s  left {_num(m['vy'], '+7.3f')} "
        f"m/s  turn {_num(turn, '+8.2f')} deg/s",
        _sigma_line(m),
        f"time             {m['t'] - t_start:9.2f} s since the watch began",
        f"mice             {m['used']} used, {state}" + _health(m, "; "),
    ]
    if m.get("gyro"):
        lines.append(f"gyro             {gyro_text(m['gyro'])}")
    return lines


def gyro_text(g: dict[str, Any]) -> str:
    """POSE's gyro (protocol 1.3): its learnt bias, and how well it agreed with the mice."""
    bias, sigma = g.get("bias"), g.get("bias_sigma")
    deg = 180 / math.pi
    text = f"bias {_num(bias, '+.3f', deg)} +- {_num(sigma, '.3f', deg)} deg/s"
    agree = g.get("agree")
    if agree is not None:
        text += f", agreement chi2 {agree:.1f}" + (" (DISAGREES)" if agree > 15.0 else "")
    return text


def _health(m: dict[str, Any], sep: str) -> str:
    """The fault-tolerant fusion's verdict on the window, in words."""
    parts = []
    for key in ("missing", "excluded", "suspect"):
        if m.get(key):
            parts.append(f"{key}: {', '.join(m[key])}")
    if m.get("consistent") is False:
        parts.append("the mice DISAGREE (uncertainty widened)")
    return "".join(sep + p for p in parts)


def pose_line(m: dict[str, Any], t_start: float) -> str:
    """One pose in one line, for a pipe or a log: the screen's fields with their units."""
    heading = None if m.get("theta") is None else wrap_degrees(m["theta"])
    turn = None if m.get("omega") is None else math.degrees(m["omega"])
    state = "updating" if m["updating"] else "NOT UPDATING"
    line = (
        f"t {m['t'] - t_start:.3f} s  odom x {_num(m['x'], '+.4f')} m  y {_num(m['y'], '+.4f')}"
        f" m  heading {_num(heading, '+.2f')} deg  body forward {_num(m['vx'], '+.3f')} m/s"
        f"  left {_num(m['vy'], '+.3f')} m/s  turn {_num(turn, '+.2f')} deg/s"
        f"  {m['used']} used, {state}"
    )
    if m.get("gyro"):
        line += f"  gyro {gyro_text(m['gyro'])}"
    return line + _health(m, "  ")


def _sigma_line(m: dict[str, Any]) -> str:
    cov = m.get("cov") or [[None] * 3] * 3
    sd = [math.sqrt(c) if c is not None and c >= 0 else None for c in (cov[i][i] for i in range(3))]
    return (
        f"1 sigma (odom)   x {_num(sd[0], '9.2f', 1e3)} mm  y {_num(sd[1], '9.2f', 1e3)} mm  "
        f"heading {_num(sd[2], '7.3f', 180 / math.pi)} deg (std dev)"
    )


def source_state(s: dict[str, Any]) -> str:
    if not s.get("connected"):
        return "gone"
    state = s.get("state")
    if state:  # the fault-tolerant engine's words: tracking, late, suspect, excluded
        return str(state)
    return "excluded" if s.get("excluded") else "tracking"


def scale_text(s: dict[str, Any]) -> str:
    """A SOURCE's learnt scale as a deviation from 1 ("+2.9 %": its counts are taken 2.9 %
    larger to agree with the others), "applied" where the fusion uses it; "-" where none
    is learnt (fewer than three mice, fault handling off, too little motion yet, or a
    daemon older than protocol 1.2)."""
    if s.get("kind") == "iio":  # the gyro: its learnt bias instead
        bias = s.get("bias")
        return "-" if bias is None else f"bias {math.degrees(bias):+.3f} deg/s"
    g = s.get("scale")
    if g is None:
        return "-"
    text = f"{round(100.0 * (g - 1.0), 1) + 0.0:+.1f} %"  # + 0.0: no "-0.0"
    return text + " applied" if s.get("scale_applied") else text


def _age(age: float | None) -> str:
    if age is None:
        return "-"
    return f"{age * 1e3:.0f} ms ago" if age < 10.0 else f"{age:.0f} s ago"


def _residual(res: float | None) -> str:
    return "-" if res is None else f"{res * 1e3:.3f} mm"


def source_line(s: dict[str, Any], color: bool = False) -> str:
    """One SOURCE in one line, every field with its name: for a pipe or a log."""
    state = source_state(s)
    parts = [
        f"{s.get('name', '?'):<10}",
        _paint(f"{state:<9}", state, color),
        f"{s.get('rate_hz') or 0:7.1f} reports/s",
        f"last {_age(s.get('age')):>11}",
        f"residual {_residual(s.get('residual')):>9}",
        f"dropped {s.get('dropped', 0)}",
    ]
    if "squal" in s:
        parts.append(f"SQUAL {s['squal']}")
    parts.append(f"scale {scale_text(s)}")
    parts += [note for note, _ in _notes(s)]
    return "  ".join(parts)


def _notes(s: dict[str, Any], dropped: bool = False) -> list[tuple[str, bool]]:
    """What a sensor's row cannot hold, in words: (text, whether it is a warning);
    ``dropped``: frames lost, if any (the table has no column for them)."""
    out = []
    if dropped and s.get("dropped"):
        out.append((f"{s['dropped']} frames dropped (reports lost by the kernel or the link)",
                    False))  # fmt: skip
    if s.get("reason"):
        out.append((f"({s['reason']})", False))
    if s.get("error") and not s.get("connected"):
        out.append((str(s["error"]), False))
    if s.get("scale_warning"):
        out.append((f"warning: {s['scale_warning']}", True))
    return out


def source_table(sources: list[dict[str, Any]], color: bool = False, width: int = 80) -> list[str]:
    """The sensors as a table (a row of column names, a row per sensor), each sensor's
    notes (frames dropped, reason, error, scale warning) wrapped to ``width`` under its
    row.  The rows fit 80 columns for names of up to 15 characters (with an ADNS-3080's
    SQUAL too)."""
    names = [str(s.get("name", "?")) for s in sources]
    nw = max([6, *map(len, names)])
    squal = any("squal" in s for s in sources)
    head = (
        f"{'sensor':<{nw}} {'state':<9}{'reports/s':>9} {'last report':>11} {'residual':>9}"
        + (f" {'SQUAL':>5}" if squal else "")
        + "  scale"
    )
    lines = [head]
    indent = " " * 4
    for name, s in zip(names, sources, strict=True):
        state = source_state(s)
        row = (
            f"{name:<{nw}} {_paint(f'{state:<9}', state, color)}{s.get('rate_hz') or 0:9.1f} "
            f"{_age(s.get('age')):>11} {_residual(s.get('residual')):>9}"
            + (f" {s.get('squal', '-')!s:>5}" if squal else "")
            + f"  {scale_text(s)}"
        )
        lines.append(row)
        for note, warn in _notes(s, dropped=True):
            wrapped = textwrap.wrap(note, max(20, width - len(indent)), break_long_words=False,
                                    break_on_hyphens=False)  # fmt: skip
            for part in wrapped:
                lines.append(indent + (f"{YELLOW}{part}{RESET}" if warn and color else part))
    return lines


def _paint(text: str, state: str, color: bool) -> str:
    if not color:
        return text
    code = {"tracking": GREEN, "late": GREEN, "suspect": YELLOW, "excluded": YELLOW,
            "gone": RED}.get(state)  # fmt: skip
    return f"{code}{text}{RESET}" if code else text


def sketch(path: list[tuple[float, float]], width: int, height: int) -> list[str]:
    """The path so far in a width x height box of characters, x (forward at start) to the
    right, y up; 'o' the start, '@' now, '.' where it went.  [] if there is no room or no
    motion yet."""
    if width < 12 or height < 4 or len(path) < 2:
        return []
    xs, ys = [p[0] for p in path], [p[1] for p in path]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    span = max(x1 - x0, (y1 - y0) * 2.0, 1e-3)  # characters are about twice as tall
    cols, rows = width - 2, height - 2
    grid = [[" "] * cols for _ in range(rows)]

    def cell(x: float, y: float) -> tuple[int, int]:
        c = int((x - x0) / span * (cols - 1))
        r = rows - 1 - int((y - y0) * 2.0 / span * (rows - 1))
        return max(0, min(rows - 1, r)), max(0, min(cols - 1, c))

    for x, y in path:
        r, c = cell(x, y)
        grid[r][c] = "."
    r, c = cell(*path[0])
    grid[r][c] = "o"
    r, c = cell(*path[-1])
    grid[r][c] = "@"
    scale = f" {span:.2f} m across "
    top = (
        "+" + scale + "-" * (cols - len(scale)) + "+"
        if cols > len(scale)
        else "+" + "-" * cols + "+"
    )
    return [top, *("|" + "".join(row) + "|" for row in grid), "+" + "-" * cols + "+"]


def screen(
    header: str,
    pose: dict[str, Any] | None,
    sources: dict[str, dict],
    t_start: float,
    path: list[tuple[float, float]],
    size: tuple[int, int],
    color: bool,
) -> list[str]:
    """The whole terminal screen: at most ``size`` = (columns, lines), no line wider than
    the columns (a wider one would wrap and push the top off).  The pose comes right after
    the header, the position and heading first, so it is never what gives way; when lines
    are short the path sketch shrinks, then goes, then the blank lines, the header's second
    line, and last the bottom of the sensor table (a line says how much is hidden)."""
    cols, rows = size
    head = textwrap.wrap(header, cols, break_on_hyphens=False) or [""]
    core = pose_lines(pose, t_start) if pose is not None else []
    table = source_table(list(sources.values()), color, cols)
    gap = [""]
    if len(head) + len(core) + len(table) + 2 > rows:
        gap = []  # no blank lines
    if len(head) + len(core) + len(table) + 2 * len(gap) > rows:
        head = [_clip(header, cols)]
    lines = head + gap + core + gap
    room = rows - len(lines)
    if len(table) > room:
        hidden = len(table) - max(0, room - 1)
        table = table[: max(0, room - 1)] + [f"({hidden} more lines of sensors: a taller "
                                             "terminal shows them)"]  # fmt: skip
    lines += table
    room = rows - len(lines) - 2  # a blank line and the sketch's title
    if pose is not None and room >= 4:
        lines += ["", "path (o start, @ now)"] + sketch(path, min(cols, 72), min(room, 20))
    return [_clip(line, cols) for line in lines[:rows]]


_ESC = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def visible_len(line: str) -> int:
    return len(_ESC.sub("", line))


def _clip(line: str, cols: int) -> str:
    """At most ``cols`` visible characters (colour codes kept, and reset if cut)."""
    if visible_len(line) <= cols:
        return line
    out, n, k = [], 0, 0
    while k < len(line) and n < cols:
        m = _ESC.match(line, k)
        if m:
            out.append(m.group())
            k = m.end()
            continue
        out.append(line[k])
        n += 1
        k += 1
    return "".join(out) + (RESET if _ESC.search(line) else "")
