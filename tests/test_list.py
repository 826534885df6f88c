"""``mousedom list`` as a real process."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from conftest import a_group, mousedom_env, run_mousedom
from test_evdev_fakes import add_device


def test_list_on_this_machine_without_dev_input():
    """The build machine has no /dev/input: say so and exit 0 (a fact, not an error)."""
    if Path("/dev/input").exists():  # a developer's desktop: it must see what is there
        p = run_mousedom("list", "--json")
        assert p.returncode == 0, p.stderr
        j = json.loads(p.stdout)
        events = [n for n in os.listdir("/dev/input") if n.startswith("event")]
        assert j["present"] is True and j["nodes"] == len(events), (j, events)
        return
    p = run_mousedom("list")
    assert p.returncode == 0, p.stderr
    assert "no input devices" in p.stdout and "/dev/input does not exist" in p.stdout
    assert p.stderr == ""
    j = json.loads(run_mousedom("list", "--json").stdout)
    assert j == {"input_dir": "/dev/input", "present": False, "nodes": 0, "devices": [],
                 "gyros": []}  # fmt: skip


def test_list_fake_machine_text_and_json(tmp_path):
    add_device(
        tmp_path,
        3,
        "Logitech USB Optical Mouse",
        phys="usb-0000:00:14.0-2/input0",
        by_id=("usb-Logitech_USB_Optical_Mouse-event-mouse",),
        by_path=("pci-0000:00:14.0-usb-0:2:1.0-event-mouse",),
        mouse_dpi="400@125 *800@125",
    )
    add_device(tmp_path, 4, "Keyboard", rel="0")
    add_device(tmp_path, 7, "BT Mouse", bustype=5, uniq="11:22:33:44:55:66", product=0xB00D)
    p = run_mousedom("list", "--root", str(tmp_path))
    assert p.returncode == 0, p.stderr
    out = p.stdout
    assert "event3  Logitech USB Optical Mouse" in out
    assert "usb 046d:c077" in out and "phys     usb-0000:00:14.0-2/input0" in out
    assert "by-path  " + str(tmp_path / "dev/input/by-path/pci-0000:00:14.0-usb-0:2:1.0") in out
    assert "MOUSE_DPI 400@125 *800@125 (800 cpi at 125 Hz)" in out
    assert "config   evdev: {path: " in out
    assert "Keyboard" not in out
    assert "uniq     11:22:33:44:55:66" in out and "bluetooth 046d:b00d" in out
    assert "2 devices with REL_X and REL_Y" in out
    j = json.loads(run_mousedom("list", "--json", "--root", str(tmp_path)).stdout)
    assert j["present"] and j["nodes"] == 3
    names = [d["name"] for d in j["devices"]]
    assert names == ["Logitech USB Optical Mouse", "BT Mouse"]
    d = j["devices"][0]
    assert d["id"] == "046d:c077" and d["dpi"]["dpi"] == 800 and d["dpi"]["hz"] == 125
    assert d["readable"] is True and d["group"] == "root"


def test_list_no_pointer_among_devices(tmp_path):
    add_device(tmp_path, 0, "Power Button", rel="0", bustype=0x19)
    p = run_mousedom("list", "--root", str(tmp_path))
    assert p.returncode == 0
    assert "no devices with REL_X and REL_Y among 1 input devices" in p.stdout


def test_list_unreadable_device_names_the_group():
    """A node the user may not open (0660 root:GROUP): list it and say which group to join.

    Run as a real process that drops to nobody (root opens anything); the interpreter
    lives under /root, so the child imports everything first and then drops privileges,
    as the daemon engineer's SO_PEERCRED test does.
    """
    import grp
    import shutil
    import subprocess
    import sys
    import tempfile

    group = a_group()
    root = Path(tempfile.mkdtemp(prefix="mousedom-list-"))
    try:
        node = add_device(root, 3, "Locked Mouse", by_path=("pci-usb-0:1-event-mouse",))
        for d, _, files in os.walk(root):
            os.chmod(d, 0o755)
            for f in files:
                os.chmod(os.path.join(d, f), 0o644)
        os.chown(node, 0, grp.getgrnam(group).gr_gid)
        os.chmod(node, 0o660)
        if os.geteuid() == 0:
            code = (
                "import os, sys\n"
                "from mousedom.cli import build_parser, main\n"
                "import mousedom.commands.list, mousedom.sources.discovery, json, grp, stat\n"
                "build_parser()\n"
                "os.setgid(65534); os.setuid(65534)\n"
                f"sys.exit(main(['list', '--root', {str(root)!r}]))\n"
            )
            p = subprocess.run(
                [sys.executable, "-c", code],
                capture_output=True,
                text=True,
                env=mousedom_env(),
                timeout=60,
            )
        else:
            p = run_mousedom("list", "--root", str(root))
        assert p.returncode == 0, p.stderr
        assert f"cannot open: permission denied on {node}: join group '{group}'" in p.stdout
        assert f"usermod -aG {group}" in p.stdout
        assert f"1 cannot be opened by this user: join group {group}" in p.stdout
        assert "event3  Locked Mouse" in p.stdout  # sysfs still describes it
    finally:
        shutil.rmtree(root)


def test_list_with_config_says_which_device_each_mouse_is(tmp_path):
    root = tmp_path / "m"
    for n in (3, 4):  # regular files as nodes: a FIFO node would read as a stream
        add_device(
            root,
            n,
            "Twin",
            phys=f"usb-{n}/input0",
            by_path=(f"pci-usb-0:{n}-event-mouse",),
            fifo=False,
        )
    fifo = tmp_path / "sim.fifo"
    os.mkfifo(fifo)
    link = root / "dev/input/by-path/pci-usb-0:4-event-mouse"
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "mice:\n"
        "  left: {cpi: 800, mount: {x: 0, y: 0.1}, evdev: {path: " + str(link) + "}}\n"
        "  right: {cpi: 800, mount: {x: 0, y: -0.1}, evdev: {path: " + str(fifo) + "}}\n"
    )
    p = run_mousedom("list", "--root", str(root), "--config", str(cfg))
    assert p.returncode == 0, p.stdout + p.stderr
    assert f"left -> {root}/dev/input/event4" in p.stdout
    assert f"right -> {fifo} (FIFO/pipe stream)" in p.stdout
    # A rule that is ambiguous: exit 1, both candidates named.
    cfg.write_text(
        "mice:\n"
        "  left: {cpi: 800, mount: {x: 0, y: 0.1}, evdev: {name: Twin}}\n"
        "  right: {cpi: 800, mount: {x: 0, y: -0.1}, evdev: {name: Gone}}\n"
    )
    p = run_mousedom("list", "--json", "--root", str(root), "--config", str(cfg))
    assert p.returncode == 1
    mice = json.loads(p.stdout)["config"]["mice"]
    assert "2 devices match name='Twin'" in mice["left"]["error"]
    assert "event3" in mice["left"]["error"] and "event4" in mice["left"]["error"]
    assert mice["right"]["node"] is None and "no input device matches" in mice["right"]["error"]


def test_list_names_the_iio_gyros_and_the_section_that_names_one(tmp_path):
    from iio_fakes import add_gyro

    add_device(tmp_path, 3, "Mouse")
    add_gyro(tmp_path, 0, "mpu6050")
    p = run_mousedom("list", "--root", str(tmp_path))
    assert p.returncode == 0, p.stderr
    assert "iio:device0  mpu6050" in p.stdout and "gyro: {name: mpu6050}" in p.stdout
    assert "1 IIO gyro" in p.stdout
    j = json.loads(run_mousedom("list", "--json", "--root", str(tmp_path)).stdout)
    assert [g["name"] for g in j["gyros"]] == ["mpu6050"]
    assert j["gyros"][0]["node"] == str(tmp_path / "dev" / "iio:device0")


@pytest.mark.parametrize("gyro, code, said", [
    ("{name: mpu6050}", 0, "gyro -> {root}/sys/bus/iio/devices/iio:device0 ({root}/dev/iio:"),
    ("{path: /sys/bus/iio/devices/iio:device0}", 0, "gyro -> {root}/sys/bus/iio/devices/iio:"),
    ("{name: nosuchgyro}", 1, "gyro: no IIO device is named 'nosuchgyro' (IIO devices: "),
    ("{path: /sys/bus/iio/devices/iio:device7}", 1, "no such IIO device"),
    ("{ros2: {topic: /imu/data}}", 0, "gyro: ROS 2 topic /imu/data"),
])  # fmt: skip
def test_list_with_config_says_which_iio_device_the_gyro_is(tmp_path, gyro, code, said):
    """``list --config`` said which device each mouse is and nothing of the gyro: it now
    says the IIO device the gyro's rule matches as the daemon finds it (under --root), or
    why none (exit 1, as for a mouse); the JSON has it under config.gyro."""
    from iio_fakes import add_gyro

    root = tmp_path / "m"
    add_device(root, 3, "Mouse", fifo=False)
    add_gyro(root, 0, "mpu6050")
    cfg = tmp_path / "rig.yaml"
    mice = ("model: diff-drive\n"
            "mice:\n  a: {cpi: 800, mount: {x: 0.1, y: 0}, evdev: {name: Mouse}}\n")  # fmt: skip
    cfg.write_text(mice + f"gyro: {gyro}\n")
    p = run_mousedom("list", "--root", str(root), "--config", str(cfg))
    assert p.returncode == code, p.stdout + p.stderr
    assert said.format(root=root) in p.stdout.split(f"{cfg}:")[1], p.stdout
    j = json.loads(run_mousedom("list", "--json", "--root", str(root), "--config", str(cfg)).stdout)
    g = j["config"]["gyro"]
    assert (g["error"] is not None) == (code == 1)
    if code == 0 and "ros2" not in gyro:
        assert g["sysfs"] == f"{root}/sys/bus/iio/devices/iio:device0"
        assert g["node"] == f"{root}/dev/iio:device0"
    # no gyro: null, and no line
    cfg.write_text(mice)
    p = run_mousedom("list", "--json", "--root", str(root), "--config", str(cfg))
    assert p.returncode == 0 and json.loads(p.stdout)["config"]["gyro"] is None
