"""Man pages and shell completion (issue 29, item 8), as scripts/gen_man.py writes them.

mousedom(1) names every command and every option of the parser ``mousedom --help`` prints,
each under its own command; mousedom.yaml(5) holds every key of docs/config.md's reference;
both render with ``man -l`` and ``groff -ww`` without a warning.  The bash completion is
valid bash and completes commands, nested commands, options, choices and files when
sourced into a real bash; the zsh one is valid zsh where zsh is installed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import REPO, mousedom_env

sys.path.insert(0, str(REPO / "scripts"))
import gen_man  # noqa: E402

from mousedom.cli import build_parser  # noqa: E402

HAVE_LIBS = all(__import__("importlib").util.find_spec(m) for m in ("argparse_manpage", "shtab"))
if not HAVE_LIBS:
    if os.environ.get("CI"):
        pytest.fail("argparse-manpage and shtab are missing in CI (the test extra has them)")
    pytest.skip("needs argparse-manpage and shtab: pip install '.[man]'", allow_module_level=True)


@pytest.fixture(scope="module")
def out(tmp_path_factory) -> Path:
    """The generated files, written by the script as a user runs it."""
    prefix = tmp_path_factory.mktemp("prefix")
    r = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "gen_man.py"), "--out", str(prefix)],
        capture_output=True, text=True, timeout=60, env=mousedom_env(),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    written = {Path(line) for line in r.stdout.split()}
    want = {prefix / p for p in (gen_man.MAN1, gen_man.MAN5, gen_man.BASH, gen_man.ZSH)}
    assert written == want and all(p.is_file() for p in want), r.stdout
    return prefix


def _plain(roff: str) -> str:
    """roff source as the words it shows: font changes and escapes removed."""
    text = re.sub(r"\\f(\[[^\]]*\]|.)", "", roff)
    text = text.replace("\\-", "-").replace("\\e", "\\")
    return re.sub(r"\\[%,/&]", "", text)


def _sections(man: str) -> dict[str, str]:
    """mousedom(1)'s text by command: each ``.SS mousedom ...`` subsection, and the top
    level's OPTIONS section under "mousedom"."""
    out = {}
    for m in re.finditer(r"^\.SS (.*?)\n(.*?)(?=^\.S[SH] |\Z)", man, re.S | re.M):
        out[m.group(1).strip()] = m.group(2)
    top = re.search(r"^\.SH OPTIONS\n(.*?)(?=^\.SH |\Z)", man, re.S | re.M)
    out["mousedom"] = top.group(1) if top else ""
    return out


def test_man1_has_every_command_and_option(out):
    man = _plain((out / gen_man.MAN1).read_text())
    sections = _sections(man)
    for name, parser in gen_man.subcommands(build_parser()):
        assert name in sections, f"mousedom(1) has no section for {name!r}"
        text = sections[name]
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if action.help == argparse.SUPPRESS:
                continue
            for option in action.option_strings or [action.metavar or action.dest]:
                # described in a paragraph of its own (not only named in the usage line)
                tag = rf"^\.TP\n[^\n]*(?<![\w-]){re.escape(option)}(?![\w-])"
                assert re.search(tag, text, re.M), f"mousedom(1): {name} {option} is missing"
            if action.help:  # the help line too, as --help prints it
                assert action.help.split("%(")[0].split()[0] in text, (name, action.help)


def test_man1_lists_the_commands_under_their_heading(out):
    man = _plain((out / gen_man.MAN1).read_text())
    assert re.search(r"^\.SH\s+COMMANDS$", man, re.M), "no COMMANDS section"  # (next line)
    for section in ("NAME", "SYNOPSIS", "EXIT STATUS", "ENVIRONMENT", "FILES", "SEE ALSO"):
        assert re.search(rf"^\.SH {section}$", man, re.M), f"mousedom(1) has no {section}"
    assert "mousedom.yaml(5)" in man


def _reference_keys(node) -> list[str]:
    """Every mapping key in a loaded YAML document, at any depth."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield str(key)
            yield from _reference_keys(value)


def test_man5_holds_the_config_reference(out):
    doc = (REPO / "docs" / "config.md").read_text()
    man = _plain((out / gen_man.MAN5).read_text())
    reference = yaml.safe_load(re.search(r"```yaml\n(.*?)```", doc, re.S).group(1))
    missing = [k for k in _reference_keys(reference) if not re.search(rf"[\s{{,]{k}:", man)]
    assert not missing, f"mousedom.yaml(5) lacks keys of docs/config.md: {missing}"
    for heading in re.findall(r"^## (.*)$", doc, re.M):
        assert f'.SH "{heading.upper()}"' in man, heading
    for example in (REPO / "config" / "examples").glob("*.yaml"):
        assert example.name in man, example.name


def test_markdown_to_roff_keeps_roff_requests_out_of_the_text():
    """A line of text that starts with a dot or quote would be taken for a request."""
    lines = gen_man.markdown_to_roff(
        ".dotfile and 'quoted' start lines\n\n    .EX inside code\n\n- a `--flag` item"
    )
    assert lines[:2] == [".PP", "\\&.dotfile and 'quoted' start lines"]
    assert "\\&.EX inside code" in lines
    assert lines[-2:] == [".IP \\(bu 2", "a \\fB\\%\\-\\-flag\\fR item"]


RENDERERS = [tool for tool in ("man", "groff") if shutil.which(tool)]


@pytest.mark.skipif(not RENDERERS, reason="neither man nor groff is installed: nothing to "
                    "render with (apt-get install man-db groff-base)")  # fmt: skip
@pytest.mark.parametrize("page", ["MAN1", "MAN5"])
def test_page_renders_without_warnings(out, page):
    path = out / getattr(gen_man, page)
    env = dict(os.environ, MANWIDTH="80", MANPAGER="cat", PAGER="cat")
    if "man" in RENDERERS:
        r = subprocess.run(["man", "-l", str(path)], capture_output=True, text=True,
                           env=env, timeout=30)  # fmt: skip
        assert r.returncode == 0 and not r.stderr, r.stderr
        title = "MOUSEDOM(1)" if page == "MAN1" else "MOUSEDOM.YAML(5)"
        assert title in r.stdout and "SEE ALSO" in r.stdout, r.stdout[:500]
    if "groff" in RENDERERS:  # every warning on: unknown requests, bad escapes, ...
        r = subprocess.run(["groff", "-man", "-Tutf8", "-ww", "-z", str(path)],
                           capture_output=True, text=True, timeout=30)  # fmt: skip
        assert r.returncode == 0 and not r.stderr, r.stderr


def test_bash_completion_is_valid_bash(out):
    r = subprocess.run(["bash", "-n", str(out / gen_man.BASH)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def _complete(out: Path, cwd: Path, *words: str) -> list[str]:
    """What Tab offers after ``words`` (the last one being completed), from the function
    the sourced script registers for mousedom (``complete -p`` names it)."""
    script = f"""
        source {out / gen_man.BASH}
        func=$(complete -p mousedom | sed -n 's/.* -F \\([^ ]*\\) .*/\\1/p')
        COMP_WORDS=("$@"); COMP_CWORD=$(( $# - 1 ))
        COMP_LINE="$*"; COMP_POINT=${{#COMP_LINE}}
        "$func" mousedom "${{COMP_WORDS[COMP_CWORD]}}" "${{COMP_WORDS[COMP_CWORD-1]}}"
        printf '%s\\n' "${{COMPREPLY[@]}}"
    """
    r = subprocess.run(["bash", "--norc", "--noprofile", "-c", script, "bash", *words],
                       capture_output=True, text=True, cwd=cwd, timeout=30)  # fmt: skip
    assert r.returncode == 0, r.stderr
    return sorted(filter(None, r.stdout.split("\n")))


def test_bash_completes_commands_options_choices_and_files(out, tmp_path):
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert _complete(out, tmp_path, "mousedom", "") == sorted(commands.choices)
    assert _complete(out, tmp_path, "mousedom", "che") == ["check-config"]
    assert _complete(out, tmp_path, "mousedom", "calibrate", "sc") == ["scales"]
    assert _complete(out, tmp_path, "mousedom", "replay", "--mo") == ["--model"]
    assert _complete(out, tmp_path, "mousedom", "replay", "--model", "") == sorted(
        ["lsq", "diff-drive", "bonarini"]
    )
    (tmp_path / "rig.yaml").touch()
    assert _complete(out, tmp_path, "mousedom", "check-config", "--config", "r") == ["rig.yaml"]


def test_zsh_completion_names_every_command(out):
    text = (out / gen_man.ZSH).read_text()
    assert text.startswith("#compdef mousedom")
    for name, _ in list(gen_man.subcommands(build_parser()))[1:]:  # not mousedom itself
        assert re.search(rf"^\s*{re.escape(name.rsplit(' ', 1)[-1])}:'", text, re.M), name


@pytest.mark.skipif(not shutil.which("zsh"), reason="zsh is not installed: its syntax "
                    "check needs it (apt-get install zsh)")  # fmt: skip
def test_zsh_completion_is_valid_zsh(out):
    r = subprocess.run(["zsh", "-n", str(out / gen_man.ZSH)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
