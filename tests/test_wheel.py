"""``python -m build`` makes a wheel that carries the compiled core, and that wheel,
installed into a fresh venv, runs it (issue 28, item 1; docs/install.md)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import venv

import cores
from conftest import REPO

# (what CI or a developer made in the checkout: .udevadm holds links to files it lacks)
SKIP = (".git", ".venv", ".ros-venv", ".udevadm", "build", "dist", "__pycache__", "*.so",
        "*.egg-info", ".hypothesis", ".pytest_cache", ".ruff_cache", ".mypy_cache",
        "firmware")  # fmt: skip

needs_gcc = cores.needs_gcc


@needs_gcc
def test_the_wheel_carries_the_core_and_a_fresh_venv_runs_it(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(*SKIP))
    built = subprocess.run(
        [sys.executable, "-m", "build", "--wheel", "--outdir", str(tmp_path / "dist"), str(src)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("mousedom-*.whl")
    listing = subprocess.run([sys.executable, "-m", "zipfile", "-l", str(wheel)],
                             capture_output=True, text=True, check=True).stdout  # fmt: skip
    assert "mousedom/_core." in listing and ".so" in listing
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    # --no-deps: the core and its switch need nothing else (the rest of mousedom does;
    # the README's commands install it with its dependencies)
    # (without the checkout on PYTHONPATH, where pip would find mousedom "installed")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MOUSEDOM_CORE")}
    subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True, timeout=300, env=env)  # fmt: skip
    probe = (
        "import struct; from mousedom import core; "
        "rec = lambda t, c, v: struct.pack('<qqHHi', 1, 5, t, c, v); "
        "empty = (0, 0, False, False, 0, 0, 0.0); "
        "out = core.native.feed_bytes(rec(2, 0, 7) + rec(0, 0, 0), empty); "
        "print(core.NAME, out[0], out[1])"
    )  # fmt: skip
    ran = subprocess.run([py, "-c", probe], capture_output=True, text=True, cwd=tmp_path,
                         env=env, timeout=60)  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.split() == ["c", "[1.000005]", "[7]"]


def test_without_a_compiler_pip_installs_the_python_alone(tmp_path):
    """Where no C compiler works (CC=/bin/false stands for a machine without gcc or the
    Python headers), ``pip install .`` still succeeds and the Python core runs."""
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(*SKIP))
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MOUSEDOM_CORE")}
    env["CC"] = "/bin/false"
    done = subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", str(src)],
                          capture_output=True, text=True, timeout=600, env=env)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    probe = "from mousedom import core; print(core.NAME)"
    ran = subprocess.run([py, "-c", probe], capture_output=True, text=True, cwd=tmp_path,
                         env=env, timeout=60)  # fmt: skip
    assert ran.stdout.strip() == "python (no compiled core built)", ran.stderr
