"""`list` and `doctor` on machines whose input folders are closed to the user, and `--root`
with a by-path rule (sources.discovery).

A /dev/input, a /dev/input/by-path or a /sys/class/input that the user may not list ended
`list` and `doctor` in a PermissionError traceback (exit 1, doctor's later checks never
printed); a config's /dev/input/by-path rule was looked up on this machine, not in the
tree `--root` names, so a bind-mounted host's rig never matched."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import mousedom_env
from test_evdev_fakes import add_device

NOBODY = 65534
RIG = (
    "rate_hz: 100\nmodel: lsq\nmice:\n"
    "  left:\n    evdev: {path: /dev/input/by-path/pci-usb-0:1-event-mouse}\n"
    "    cpi: 1000\n    mount: {x: 0, y: 0.13, yaw: 0}\n"
    "  right:\n    evdev: {name: 'Right Mouse'}\n"
    "    cpi: 1000\n    mount: {x: 0, y: -0.13, yaw: 0}\n"
)


@pytest.fixture
def shared():
    """A folder another user may enter (pytest's tmp_path parents are 0700 for root)."""
    d = Path(tempfile.mkdtemp(prefix="mousedom-perm-"))
    os.chmod(d, 0o755)
    yield d
    for dirpath, dirnames, _ in os.walk(d):
        for n in dirnames:
            os.chmod(os.path.join(dirpath, n), 0o755)
    shutil.rmtree(d)


def _rig(root: Path) -> Path:
    add_device(root, 3, "Left Mouse", by_path=("pci-usb-0:1-event-mouse",))
    add_device(root, 4, "Right Mouse")
    for dirpath, _, filenames in os.walk(root):
        os.chmod(dirpath, 0o755)
        for f in filenames:
            p = os.path.join(dirpath, f)
            if not os.path.islink(p):
                os.chmod(p, os.stat(p).st_mode | 0o044)
    config = root / "rig.yaml"
    config.write_text(RIG)
    os.chmod(config, 0o644)
    return config


def _as_another_user(*args: str) -> subprocess.CompletedProcess:
    """`mousedom ARGS` as a user the closed folders are closed to: nobody when we are root
    (root reads everything), else ourselves."""
    prefix = []
    if os.getuid() == 0:
        prefix = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
    return subprocess.run([*prefix, sys.executable, "-m", "mousedom", *args],
                          capture_output=True, text=True, timeout=120,
                          env=mousedom_env())  # fmt: skip


@pytest.mark.parametrize("closed", ["dev/input", "dev/input/by-path", "sys/class/input"])
def test_a_folder_closed_to_the_user_is_said_not_a_traceback(shared, closed):
    config = _rig(shared)
    os.chmod(shared / closed, 0o700)
    socket = str(shared / "none.sock")
    runs = {
        "list": _as_another_user("list", "--root", str(shared)),
        "list --config": _as_another_user("list", "--root", str(shared), "--config", str(config)),
        "doctor": _as_another_user(
            "doctor", "--root", str(shared), "--config", str(config), "--socket", socket
        ),  # fmt: skip
    }
    for what, p in runs.items():
        assert "Traceback" not in p.stderr + p.stdout, (what, p.stderr)
    if closed == "dev/input":
        # the devices are unknown: said, and a failure (a rig's mice cannot be checked)
        said = f"{shared}/dev/input: cannot list it: Permission denied"
        for what, p in runs.items():
            assert p.returncode == 1 and said in p.stdout + p.stderr, (what, p.stdout)
        assert "FAIL" in runs["doctor"].stdout
        assert "socket" in runs["doctor"].stdout  # the checks after the devices still ran
    else:
        assert runs["list"].returncode == 0, runs["list"].stderr
    if closed == "dev/input/by-path":
        # the devices are still described, without their links
        assert "Right Mouse" in runs["list"].stdout


def test_a_by_path_rule_is_looked_up_under_root(shared):
    config = _rig(shared)
    p = subprocess.run([sys.executable, "-m", "mousedom", "list", "--root", str(shared),
                        "--config", str(config)], capture_output=True, text=True,
                       timeout=120, env=mousedom_env())  # fmt: skip
    assert p.returncode == 0, p.stdout + p.stderr
    assert f'config   evdev: {{path: "{shared}/dev/input/by-path/pci-usb-0:1-event-mouse"}}' in (
        p.stdout
    )
    assert "no input device matches" not in p.stdout


def test_a_scan_resolves_each_link_once(tmp_path, monkeypatch):
    """The scan resolved every by-id and by-path link for every node: 0.7 s for 100 nodes,
    73 s for 1,000, paid again at each retry of a missing mouse (every second).  Each link
    is resolved once a scan now, and each node's links are still its own."""
    from test_evdev_fakes import add_device

    from mousedom.sources import discovery

    n = 60
    for i in range(n):
        add_device(tmp_path, i, f"M{i}", phys=f"usb-{i}/input0", by_path=(f"p{i}-event-mouse",),
                   by_id=(f"id{i}-event-mouse",), fifo=False)  # fmt: skip
    calls = 0
    real = os.path.realpath

    def counted(path, *a, **kw):
        nonlocal calls
        calls += 1
        return real(path, *a, **kw)

    monkeypatch.setattr(discovery.os.path, "realpath", counted)
    found = discovery.scan(discovery.SystemPaths.under(str(tmp_path))).devices
    assert len(found) == n and calls <= 4 * n, calls
    for d in found:
        k = d.name[1:]
        assert [os.path.basename(p) for p in d.by_path] == [f"p{k}-event-mouse"]
        assert [os.path.basename(p) for p in d.by_id] == [f"id{k}-event-mouse"]
