"""Every code block in README.md and docs/ runs as pasted (issue 14, item 2).

Fenced blocks carry their kind: ``python`` and ``sh`` blocks are run, each in a fresh
directory, with the bundled demo daemon running and its socket where the client and
``mousedom watch`` look first ($RUNTIME_DIRECTORY); ``yaml`` blocks must load as a rig
config (or, where the comment before them says so, as a calibration file); ``text`` blocks
are samples of output and formats, not code.  An untagged block fails: whoever adds one
says what it is.  A program that runs until stopped (a pose loop) passes when it is still
running without an error after a few seconds.  The README's two set-up commands are
indented blocks, run by CI itself.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from conftest import REPO, mousedom_env

FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```\s*$", re.S | re.M)
KINDS = {"python", "sh", "yaml", "text"}
RUN_S = 4.0  # a program still running this long without an error is a loop that works


def _blocks() -> list[tuple[str, int, str, str, str]]:
    """(file, line, kind, code, the line before the block) of every fenced block."""
    out = []
    for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = path.read_text()
        for m in FENCE.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1]
            out.append((path.name, line, m.group(1).strip(), m.group(2), before))
    return out


BLOCKS = _blocks()
IDS = [f"{f}:{line}" for f, line, *_ in BLOCKS]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The bundled demo daemon, with its socket where clients look first."""
    run_dir = tmp_path_factory.mktemp("run")
    env = mousedom_env(RUNTIME_DIRECTORY=str(run_dir))
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--demo"],
        stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    deadline = time.monotonic() + 30
    while "listening on" not in proc.stderr.readline():
        assert time.monotonic() < deadline and proc.poll() is None, "the demo did not start"
    drain = threading.Thread(target=proc.stderr.read, daemon=True)
    drain.start()
    # The venv's own bin first, as after `. .venv/bin/activate`; nothing else of ours.
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.pop("PYTHONPATH", None)
    yield env
    proc.terminate()
    proc.wait(10)


def test_every_block_says_what_it_is():
    untagged = [f"{f}:{line}" for f, line, kind, *_ in BLOCKS if kind not in KINDS]
    assert not untagged, f"blocks without a kind ({', '.join(sorted(KINDS))}): {untagged}"


def _fifo_reader(path: Path) -> threading.Thread:
    """Opens a FIFO for reading once it exists and drains it (what mousedom would do)."""

    def read() -> None:
        deadline = time.monotonic() + 10
        while not path.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        with open(path, "rb") as f:
            f.read()

    th = threading.Thread(target=read, daemon=True)
    th.start()
    return th


def _run(argv: list[str], env: dict, cwd: Path) -> None:
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        out, err = proc.communicate(timeout=RUN_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        assert "Traceback" not in err and "Error" not in err, err
        return  # still running without an error: a loop that works
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out}\n{err}"


@pytest.mark.parametrize("file, line, kind, code, before", BLOCKS, ids=IDS)
def test_the_block_runs_as_pasted(file, line, kind, code, before, demo, tmp_path):
    if kind == "text":
        return  # a sample, not code
    if kind == "yaml":
        doc = yaml.safe_load(code)
        if "calibration file" in before:
            assert set(doc) <= {"mice", "distance", "umbmark", "notes"}
            for values in doc["mice"].values():
                assert set(values) <= {"cpi", "mount", "scale"}
            return
        from mousedom.config import parse_config

        parse_config(code, f"{file}:{line}", need_sources=False, need_model=False)
        return
    if "reader drains" in before:
        _fifo_reader(tmp_path / re.search(r"drains (\S+) -->", before).group(1))
    if kind == "python":
        (tmp_path / "block.py").write_text(code)
        _run([sys.executable, "block.py"], demo, tmp_path)
    else:  # sh
        (tmp_path / "block.sh").write_text("set -e\n" + code)
        _run(["bash", "block.sh"], demo, tmp_path)
