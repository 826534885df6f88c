"""The commands the program prints run when pasted into a new terminal (issue 14, item 1)."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time

from conftest import REPO, mousedom_env

from mousedom import invocation


def test_python_m_gives_this_interpreter_with_its_full_path(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/x/mousedom/__main__.py", "run"])
    assert invocation.command("watch", "--socket", "/run/a b") == (
        f"{shlex.quote(sys.executable)} -m mousedom watch --socket '/run/a b'"
    )


def test_a_venv_script_not_on_path_is_given_whole(monkeypatch, tmp_path):
    script = tmp_path / "venv" / "bin" / "mousedom"
    script.parent.mkdir(parents=True)
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    monkeypatch.setattr(sys, "argv", [str(script)])
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    assert invocation.command("watch") == f"{script} watch"
    monkeypatch.setenv("PATH", str(script.parent))  # the venv is active: the plain name works
    assert invocation.command("watch") == "mousedom watch"


def test_the_demo_s_watch_line_works_pasted_into_a_terminal_without_the_venv(tmp_path):
    sock = tmp_path / "demo.sock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--demo", "--socket", str(sock)],
        stderr=subprocess.PIPE, text=True, env=mousedom_env(),
    )  # fmt: skip
    try:
        line = ""
        deadline = time.monotonic() + 30
        while "watch it with: " not in line:
            assert time.monotonic() < deadline and proc.poll() is None
            line = proc.stderr.readline()
        pasted = line.split("watch it with: ", 1)[1].strip() + " --count 3 --json"
        # A new terminal: no venv on PATH, no PYTHONPATH, run from another directory.
        out = subprocess.run(
            pasted, shell=True, capture_output=True, text=True, timeout=30, cwd="/",
            env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)},
        )  # fmt: skip
        assert out.returncode == 0, (pasted, out.stderr)
        classes = [json.loads(line)["class"] for line in out.stdout.splitlines()]
        assert classes.count("POSE") == 3, classes
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stderr.close()
    assert str(REPO)  # the demo ran from this checkout
