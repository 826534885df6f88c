#!/usr/bin/env python3
"""Man pages and shell completion for mousedom, generated from their sources (issue 29, item 8).

    python scripts/gen_man.py --out PREFIX

writes, laid out as under an installation prefix (``--out /usr/local`` installs them,
``--out ~/.local`` for one user):

    share/man/man1/mousedom.1                     mousedom(1): every command and option
    share/man/man5/mousedom.yaml.5                mousedom.yaml(5): the rig config
    share/bash-completion/completions/mousedom    bash completion
    share/zsh/site-functions/_mousedom            zsh completion

mousedom(1) and both completions come from the argparse parser that ``mousedom --help``
prints (``mousedom.cli.build_parser``), so they cannot disagree with it; mousedom.yaml(5)
from docs/config.md, the config reference, with a list of the example rigs of
config/examples/.  Nothing is kept generated in the repository: it would go stale.

The libraries (the ``man`` extra: ``pip install '.[man]'``), both used only here, never by
mousedom at run time:

- argparse-manpage turns a parser, nested subcommands included, into a man page with the
  parser's own descriptions and help lines (kept by the Fedora/Red Hat packagers, used by
  pipx among others).
- shtab writes static bash and zsh completion scripts from the parser.  argcomplete, the
  other well-kept choice, would hook into ``mousedom``'s start-up and run it on every Tab
  press (importing every command: about 0.3 s a press); shtab's script is plain shell.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import os
import re
import sys
import time
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # document this checkout, not whatever is installed

# Where each file goes under the prefix.
MAN1 = Path("share/man/man1/mousedom.1")
MAN5 = Path("share/man/man5/mousedom.yaml.5")
BASH = Path("share/bash-completion/completions/mousedom")
ZSH = Path("share/zsh/site-functions/_mousedom")

SHORT = "optical-mouse odometry for robots"


# --------------------------------------------------------------------------- the parser


def subcommands(
    parser: argparse.ArgumentParser, prefix: str = "mousedom"
) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """(``mousedom calibrate cpi``, its parser) for every command, the top one first."""
    yield prefix, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from subcommands(sub, f"{prefix} {name}")


def _parser() -> argparse.ArgumentParser:
    from mousedom.cli import build_parser

    parser = build_parser()
    parser._positionals.title = "commands"  # the man page's heading for them
    return parser


def page_date() -> str:
    """The pages' date: $SOURCE_DATE_EPOCH's (reproducible builds), else today's (UTC)."""
    stamp = int(os.environ.get("SOURCE_DATE_EPOCH") or time.time())
    return datetime.datetime.fromtimestamp(stamp, datetime.timezone.utc).strftime("%Y-%m-%d")


@contextlib.contextmanager
def _wide_help() -> Iterator[None]:
    """argparse wraps help to $COLUMNS; the man page fills its own lines: no wrapping."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100000"
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


# --------------------------------------------------------------------------- roff


def roff_escape(text: str) -> str:
    """Text as roff prints it: backslashes, hyphens (options must stay minus signs, for
    copying and searching), characters outside ASCII as named Unicode glyphs."""
    text = text.replace("\\", "\\e").replace("-", "\\-")
    return "".join(c if ord(c) < 128 else f"\\[u{ord(c):04X}]" for c in text)


def _line(text: str) -> str:
    """A text line that roff will not take for a request (one starting with . or ')."""
    return "\\&" + text if text.startswith((".", "'")) else text


def _inline(text: str) -> str:
    """Markdown's inline marks in roff: `code` (never hyphenated) and **strong** bold,
    [text](link) as text (link), other characters escaped."""
    out = []
    for i, part in enumerate(re.split(r"`([^`]*)`", text)):
        if i % 2:
            out.append(f"\\fB\\%{roff_escape(part)}\\fR")  # \% before a word: no hyphen
            continue
        part = re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r"\1 (\2)", part)
        pieces = re.split(r"\*\*(.+?)\*\*", part)
        out.append(
            "".join(
                f"\\fB{roff_escape(p)}\\fR" if j % 2 else roff_escape(p)
                for j, p in enumerate(pieces)
            )
        )
    return _line("".join(out))


def markdown_to_roff(text: str) -> list[str]:
    """The markdown of docs/ (headings, paragraphs, fenced and indented code, lists) as
    man(7) requests.  The first-level heading is left out: the page has its own title."""
    out: list[str] = []
    para: list[str] = []
    item = False  # the paragraph is a list item

    def flush() -> None:
        nonlocal item
        if para:
            out.extend([".IP \\(bu 2" if item else ".PP", _inline(" ".join(para))])
        para.clear()
        item = False

    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("<!--"):  # notes for the doc tests
            while "-->" not in lines[i]:
                i += 1
            i += 1
            continue
        if line.startswith("```"):
            flush()
            end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
            out.extend([".PP", ".EX", *(_line(roff_escape(x)) for x in lines[i + 1 : end])])
            out.append(".EE")
            i = end + 1
            continue
        heading = re.match(r"(#+)\s+(.*)", line)
        if heading:
            flush()
            level, title = len(heading.group(1)), heading.group(2).replace('"', "'")
            if level == 2:
                out.append(f'.SH "{roff_escape(title.upper())}"')
            elif level > 2:
                out.append(f'.SS "{roff_escape(title)}"')
            i += 1
            continue
        if line.startswith("    ") and not para:  # an indented code block
            end = i
            while end < len(lines) and (lines[end].startswith("    ") or not lines[end].strip()):
                end += 1
            while not lines[end - 1].strip():
                end -= 1
            out.extend([".PP", ".EX", *(_line(roff_escape(x[4:])) for x in lines[i:end])])
            out.append(".EE")
            i = end
            continue
        bullet = re.match(r"[-*]\s+(.*)", line)
        if bullet:
            flush()
            item = True
            para.append(bullet.group(1))
        elif not line.strip():
            flush()
        else:
            para.append(line.strip())
        i += 1
    flush()
    return out


# --------------------------------------------------------------------------- mousedom(1)

MAN1_EXTRA = r"""
.SH EXIT STATUS
0 on success; 1 when a check the command was asked for fails (\fBcheck\-config
\-\-require\-devices\fR, \fBlist \-\-config\fR); 2 on a usage error or a problem with the
input (a config, a capture, a file), reported as one line naming the file, line and key;
130 when interrupted.
.SH ENVIRONMENT
.TP
.B RUNTIME_DIRECTORY\fR, \fBXDG_RUNTIME_DIR\fR, \fBTMPDIR
where the daemon puts its socket when the config does not say, and where \fBwatch\fR
and the client look for it: $RUNTIME_DIRECTORY (systemd), then /run/mousedom as root,
then $XDG_RUNTIME_DIR/mousedom, then $TMPDIR/mousedom\-UID.
.TP
.B NO_COLOR
\fBwatch\fR shows the sensors' states without colour.
.TP
.B ROS_DOMAIN_ID
the ROS 2 output's DDS domain, where the config sets none.
.TP
.B ROS_AUTOMATIC_DISCOVERY_RANGE\fR, \fBROS_STATIC_PEERS\fR, \fBROS_LOCALHOST_ONLY
the ROS 2 output's discovery, as ROS 2 reads them.
.TP
.B CYCLONEDDS_URI
Cyclone DDS settings for the ROS 2 output, applied after mousedom's own.
.TP
.B NOTIFY_SOCKET\fR, \fBJOURNAL_STREAM
set by systemd: readiness and watchdog notifications; log lines with their priority.
.SH FILES
.TP
.I /etc/mousedom/mousedom.yaml
the rig config \fBrun\fR and the other commands read unless \fB\-\-config\fR says
otherwise; see \fBmousedom.yaml\fR(5).
.TP
.I /run/mousedom/mousedom.sock
the daemon's socket as root or under systemd (newline\-delimited JSON: VERSION, POSE,
SOURCE, ERROR).
.SH SEE ALSO
\fBmousedom.yaml\fR(5), \fBudevadm\fR(8), \fBsystemd.service\fR(5).
The documents in the source's docs/ folder: models.md, config.md, daemon.md, protocol.md,
captures.md, calibration.md, ros2.md, firmware.md.
"""


def man1() -> str:
    """mousedom(1): the parser's commands, options and help, as argparse-manpage lays
    them out (one COMMANDS section, a subsection per command), and the sections argparse
    knows nothing of."""
    from argparse_manpage.manpage import Manpage

    from mousedom import __version__

    with _wide_help():
        page = str(
            Manpage(
                _parser(),
                {
                    "project_name": "mousedom",
                    "version": __version__,
                    "manual_title": "mousedom manual",
                    "manual_section": 1,
                    "description": SHORT,
                    "date": page_date(),
                },
                format="single-commands-section",
            )
        )
    head, rest = page.split("\n", 1)
    # No hyphenation, ragged right: option names must not be split or stretched.
    return f"{head}\n.nh\n.ad l\n{rest.rstrip()}\n{MAN1_EXTRA.strip()}\n"


# --------------------------------------------------------------------------- mousedom.yaml(5)


def _examples() -> list[str]:
    """A tagged paragraph per example rig: its file name and the first line of its
    opening comment (what it is)."""
    out = []
    for path in sorted((REPO / "config" / "examples").glob("*.yaml")):
        first = []
        for line in path.read_text().splitlines():
            if not line.startswith("#") or not line[1:].strip():
                break
            first.append(line[1:].strip())
        out.extend([".TP", f".I {roff_escape(path.name)}", _inline(" ".join(first))])
    return out


def man5() -> str:
    """mousedom.yaml(5): docs/config.md, with the example rigs listed."""
    from mousedom import __version__

    text = (REPO / "docs" / "config.md").read_text()
    return (
        "\n".join(
            [
                f'.TH MOUSEDOM.YAML "5" "{page_date()}" "mousedom {__version__}" "mousedom manual"',
                ".SH NAME",
                "mousedom.yaml \\- rig configuration of mousedom(1)",
                ".SH SYNOPSIS",
                ".I /etc/mousedom/mousedom.yaml",
                ".SH DESCRIPTION",
                *markdown_to_roff(text),
                ".SH EXAMPLES",
                "The source's config/examples/ folder has a rig for each common layout, each "
                "opening with when to choose it and what it can and cannot see "
                "(\\fBmousedom check\\-config \\-\\-config\\fR \\fIFILE\\fR prints the rig "
                "and its blind spots):",
                *_examples(),
                ".SH SEE ALSO",
                "\\fBmousedom\\fR(1); docs/config.md in the source, from which this page is made; "
                "docs/models.md for the models and what each rig can see.",
            ]
        )
        + "\n"
    )


# --------------------------------------------------------------------------- completion


def _completion_hints(parser: argparse.ArgumentParser) -> None:
    """Tell shtab which arguments are files or folders (by their metavar), so that Tab
    completes paths there; the rest complete their choices or nothing."""
    import shtab

    for _, sub in subcommands(parser):
        for action in sub._actions:
            metavar = action.metavar if isinstance(action.metavar, str) else ""
            if metavar == "DIR":
                action.complete = shtab.DIRECTORY  # type: ignore[attr-defined]
            elif "=" not in metavar and re.search(r"(FILE|PATH|\.\w+)$", metavar):
                action.complete = shtab.FILE  # type: ignore[attr-defined]


def completion(shell: str) -> str:
    """The completion script of ``shell`` (bash or zsh) for ``mousedom``."""
    import shtab

    parser = _parser()
    _completion_hints(parser)
    for _, sub in subcommands(parser):  # zsh lists commands by description, else help:
        sub.description = None  # the one-line help is what fits beside a name
    return shtab.complete(parser, shell=shell)


# --------------------------------------------------------------------------- main


def generate(prefix: Path) -> list[Path]:
    """Write every file under prefix; return their paths."""
    written = []
    for rel, text in (
        (MAN1, man1()),
        (MAN5, man5()),
        (BASH, completion("bash")),
        (ZSH, completion("zsh")),
    ):
        path = prefix / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--out", required=True, type=Path, metavar="PREFIX",
        help="write under PREFIX/share/... (/usr/local, ~/.local, or a folder to look at)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    try:
        written = generate(args.out.expanduser())
    except ModuleNotFoundError as e:
        if e.name in ("argparse_manpage", "shtab"):
            print(f"gen_man.py: {e.name} is missing: pip install '.[man]'", file=sys.stderr)
            return 2
        raise
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
