"""Every code block in README.md and docs/ runs as pasted (issue 14, item 2).

Fenced blocks carry their kind: ``python`` and ``sh`` blocks are run, each in a fresh
directory, with the bundled demo daemon running and its socket where the client and
``mousedom watch`` look first ($RUNTIME_DIRECTORY); ``yaml`` blocks are rig configs that
``mousedom check-config --no-sources`` passes as pasted, without a warning (issue 29, item
3), except those marked: a block whose first line is a ``# fragment`` comment is part of a
config, checked merged into a minimal whole one (and must not pass alone: then it is no
fragment), and one after ``<!-- doc-test: calibration file -->`` is a calibration file,
checked as the calibration of a minimal config; ``text`` blocks are samples of output and
formats, not code.  An untagged block fails: whoever adds one says what it is.  A program
that runs until stopped (a pose loop) passes when it is still running without an error
after a few seconds.  The README's two set-up commands are
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
from conftest import REPO, mousedom_env, run_mousedom

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
RUN = [b for b in BLOCKS if b[2] != "yaml"]  # run, or samples
YAML = [b for b in BLOCKS if b[2] == "yaml"]  # checked with check-config
FRAGMENT = "# fragment"  # the first line of a yaml block that is part of a config
# The smallest whole config a fragment (or a calibration file) is checked within: two mice
# (lsq's minimum) without sources, as --no-sources allows.
BASE = {
    "model": "lsq",
    "mice": {
        "left": {"cpi": 800, "mount": {"x": 0.0, "y": 0.1, "yaw": 0}},
        "right": {"cpi": 800, "mount": {"x": 0.0, "y": -0.1, "yaw": 0}},
    },
}


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


def _ids(blocks: list) -> list[str]:
    return [f"{f}:{line}" for f, line, *_ in blocks]


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


def _merged(base: dict, part: dict) -> dict:
    """base with part merged in, mappings key by key (part wins)."""
    out = dict(base)
    for key, value in part.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merged(out[key], value)
        else:
            out[key] = value
    return out


def _check_config(rig: Path) -> subprocess.CompletedProcess:
    return run_mousedom("check-config", "--no-sources", "--config", str(rig), timeout=30)


def _placeholders(doc: dict, where: Path) -> None:
    """The captures a config's replay sources name, as small native captures holding a
    device for each mouse that names the file (its replay.device as the device's name and
    recorded node): check-config opens them and maps their devices onto the mice, as
    `mousedom run` would."""
    import numpy as np

    from mousedom.capture import DeviceInfo, NativeWriter

    files: dict[str, list[DeviceInfo]] = {}
    for name, mouse in (doc.get("mice") or {}).items():
        replay = mouse.get("replay") if isinstance(mouse, dict) else None
        file = replay.get("file") if isinstance(replay, dict) else replay
        device = replay.get("device") if isinstance(replay, dict) else None
        if isinstance(file, str) and not Path(file).is_absolute():
            info = DeviceInfo(name=str(device or f"sim {name}"), mouse=str(name),
                              extra={"node": device} if device else {})  # fmt: skip
            files.setdefault(file, []).append(info)
    for file, devices in files.items():
        (where / file).parent.mkdir(parents=True, exist_ok=True)
        with NativeWriter(where / file, devices) as w:
            for i in range(len(devices)):
                w.motion(i, np.array([1.0, 2.0]), np.array([1, 1]), np.array([0, 0]))


@pytest.mark.parametrize("file, line, kind, code, before", YAML, ids=_ids(YAML))
def test_the_yaml_block_is_a_valid_config(file, line, kind, code, before, tmp_path):
    doc = yaml.safe_load(code)
    rig = tmp_path / "rig.yaml"
    if "calibration file" in before:
        (tmp_path / "calib.yaml").write_text(code)
        base = _merged(BASE, {"calibration": "calib.yaml"})
        for i, name in enumerate(set(doc.get("mice") or {}) - set(BASE["mice"])):
            base["mice"][name] = {"cpi": 800, "mount": {"x": 0.1 * (i + 1), "y": 0.0}}
        rig.write_text(yaml.safe_dump(base, sort_keys=False))
        where = f"as the calibration file of\n{rig.read_text()}"
    elif code.startswith(FRAGMENT):
        rig.write_text(code)
        alone = _check_config(rig)
        assert alone.returncode != 0, f"{file}:{line} passes alone: drop its {FRAGMENT!r} mark"
        rig.write_text(f"# {file}:{line} merged into a minimal config\n"
                       + yaml.safe_dump(_merged(BASE, doc), sort_keys=False))  # fmt: skip
        where = f"merged into a minimal config:\n{rig.read_text()}"
    else:
        rig.write_text(code)
        where = "as pasted"
    _placeholders(yaml.safe_load(rig.read_text()), tmp_path)
    r = _check_config(rig)
    assert r.returncode == 0, f"{file}:{line} {where}\n{r.stdout}{r.stderr}"
    assert "warning" not in r.stderr, f"{file}:{line} {where}\n{r.stderr}"


@pytest.mark.parametrize("file, line, kind, code, before", RUN, ids=_ids(RUN))
def test_the_block_runs_as_pasted(file, line, kind, code, before, demo, tmp_path):
    if kind == "text":
        return  # a sample, not code
    if "reader drains" in before:
        _fifo_reader(tmp_path / re.search(r"drains (\S+) -->", before).group(1))
    if kind == "python":
        (tmp_path / "block.py").write_text(code)
        _run([sys.executable, "block.py"], demo, tmp_path)
    else:  # sh
        (tmp_path / "block.sh").write_text("set -e\n" + code)
        _run(["bash", "block.sh"], demo, tmp_path)
