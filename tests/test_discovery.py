"""Device discovery on machines described as directory trees, and rule matching as data."""

from __future__ import annotations

import os

import pytest
from test_evdev_fakes import add_device, paths

from mousedom.config import EvdevMatch
from mousedom.errors import UserError
from mousedom.sources.discovery import (
    AmbiguousDevice,
    DeviceInfo,
    NoDevice,
    join_group_hint,
    match_device,
    parse_bitmask,
    parse_mouse_dpi,
    parse_udev_db,
    scan,
)


def test_parse_mouse_dpi_hwdb_forms():
    assert parse_mouse_dpi("1000@125") == {"raw": "1000@125", "dpi": 1000, "hz": 125, "choices": 1}
    d = parse_mouse_dpi("400@125 *800@125 1600@125")
    assert (d["dpi"], d["hz"], d["choices"]) == (800, 125, 3)
    assert parse_mouse_dpi("800")["dpi"] == 800
    assert parse_mouse_dpi("400 800")["dpi"] is None  # several and no default: unknown
    assert parse_mouse_dpi("fast")["dpi"] is None
    assert parse_mouse_dpi(None) is None


def test_parse_udev_db_and_bitmask():
    props = parse_udev_db("S:input/by-id/x\nE:ID_INPUT_MOUSE=1\nE:MOUSE_DPI=800@500\nG:seat\n")
    assert props == {"ID_INPUT_MOUSE": "1", "MOUSE_DPI": "800@500"}
    assert parse_bitmask("1c3") == 0x1C3
    assert parse_bitmask("1 0") == 1 << 64  # words are longs, most significant first
    assert parse_bitmask("") == 0


def test_scan_absent_dev_input(tmp_path):
    s = scan(paths(tmp_path))
    assert not s.present and s.devices == []


def test_scan_describes_pointers_only(tmp_path):
    add_device(
        tmp_path,
        3,
        "Logitech USB Optical Mouse",
        phys="usb-0000:00:14.0-2/input0",
        by_id=("usb-Logitech_USB_Optical_Mouse-event-mouse",),
        by_path=("pci-0000:00:14.0-usb-0:2:1.0-event-mouse",),
        mouse_dpi="1000@125",
    )
    add_device(tmp_path, 4, "AT Translated Set 2 keyboard", rel="0", bustype=0x11)
    add_device(tmp_path, 10, "Wheel only", rel="100")  # REL_WHEEL, no REL_X/REL_Y
    s = scan(paths(tmp_path))
    assert s.present and s.nodes == 3
    (d,) = s.devices
    assert d.name == "Logitech USB Optical Mouse"
    assert (d.vendor, d.product, d.bus) == (0x046D, 0xC077, "usb")
    assert d.by_id == (
        str(tmp_path / "dev/input/by-id/usb-Logitech_USB_Optical_Mouse-event-mouse"),
    )
    assert d.by_path[0].endswith("pci-0000:00:14.0-usb-0:2:1.0-event-mouse")
    assert d.mouse_dpi == "1000@125"
    assert d.as_dict()["dpi"]["dpi"] == 1000
    assert d.readable and d.group == "root"
    everything = scan(paths(tmp_path), pointers_only=False)
    assert [x.name for x in everything.devices] == [
        "Logitech USB Optical Mouse",
        "AT Translated Set 2 keyboard",
        "Wheel only",
    ]


MICE = [
    DeviceInfo(
        "/dev/input/event3",
        "Logitech USB Optical Mouse",
        "usb-0000:00:14.0-2/input0",
        "",
        3,
        0x046D,
        0xC077,
        rel_x=True,
        rel_y=True,
        by_id=("/dev/input/by-id/usb-Logitech_USB_Optical_Mouse-event-mouse",),
        by_path=("/dev/input/by-path/pci-0000:00:14.0-usb-0:2:1.0-event-mouse",),
    ),
    DeviceInfo(
        "/dev/input/event5",
        "Logitech USB Optical Mouse",
        "usb-0000:00:14.0-3/input0",
        "",
        3,
        0x046D,
        0xC077,
        rel_x=True,
        rel_y=True,
        by_id=("/dev/input/by-id/usb-Logitech_USB_Optical_Mouse-event-mouse",),  # same id!
        by_path=("/dev/input/by-path/pci-0000:00:14.0-usb-0:3:1.0-event-mouse",),
    ),
    DeviceInfo(
        "/dev/input/event7",
        "BT Mouse",
        "aa:bb",
        "11:22:33:44:55:66",
        5,
        0x046D,
        0xB00D,
        rel_x=True,
        rel_y=True,
    ),
    DeviceInfo("/dev/input/event8", "Keyboard", "", "", 0x11, 1, 1),  # not a pointer
]


def test_match_by_path_link_and_node():
    r = EvdevMatch(path="/dev/input/by-path/pci-0000:00:14.0-usb-0:3:1.0-event-mouse")
    assert match_device(r, MICE).node == "/dev/input/event5"
    assert match_device(EvdevMatch(path="/dev/input/event3"), MICE).node == "/dev/input/event3"
    # a custom udev symlink: matched through the resolved path
    r = EvdevMatch(path="/dev/robot-left")
    assert match_device(r, MICE, resolved_path="/dev/input/event5").node == "/dev/input/event5"


def test_match_by_name_and_phys_and_by_vendor_product_uniq():
    r = EvdevMatch(name="Logitech USB Optical Mouse", phys="usb-0000:00:14.0-2/input0")
    assert match_device(r, MICE).node == "/dev/input/event3"
    r = EvdevMatch(vendor=0x046D, product=0xB00D, uniq="11:22:33:44:55:66")
    assert match_device(r, MICE).node == "/dev/input/event7"


def test_ambiguity_lists_every_candidate():
    for r in (
        EvdevMatch(name="Logitech USB Optical Mouse"),
        EvdevMatch(path="/dev/input/by-id/usb-Logitech_USB_Optical_Mouse-event-mouse"),
        EvdevMatch(vendor=0x046D, product=0xC077),
    ):
        with pytest.raises(AmbiguousDevice) as e:
            match_device(r, MICE, who="left")
        msg = str(e.value)
        assert msg.startswith("left: 2 devices match")
        assert "/dev/input/event3" in msg and "/dev/input/event5" in msg
        assert "usb-0000:00:14.0-2/input0" in msg and "usb-0000:00:14.0-3/input0" in msg
        assert isinstance(e.value, UserError)


def test_no_match_names_the_rule_and_skips_non_pointers():
    with pytest.raises(NoDevice) as e:
        match_device(EvdevMatch(name="Keyboard"), MICE)
    assert "name='Keyboard'" in str(e.value)
    assert "event8" not in str(e.value)  # only pointer devices are candidates
    with pytest.raises(NoDevice):
        match_device(EvdevMatch(name="BT Mouse", uniq="other"), MICE)


def test_join_group_hint_names_the_group():
    hint = join_group_hint(DeviceInfo("/dev/input/event3", group="input"))
    assert "/dev/input/event3" in hint and "group 'input'" in hint and "usermod -aG input" in hint


def test_scan_without_sysfs_falls_back_to_python_evdev(tmp_path):
    """No /sys/class/input: each node is opened with python-evdev; nodes that are not
    evdev devices (here a FIFO and a regular file) are left out, nothing crashes."""
    import shutil

    add_device(tmp_path, 1, "A")
    add_device(tmp_path, 2, "B", fifo=False)
    shutil.rmtree(tmp_path / "sys")
    s = scan(paths(tmp_path))
    assert s.present and s.nodes == 2 and s.devices == []


def test_a_fifo_or_device_in_a_fake_sysfs_tree_never_blocks_the_scan(tmp_path):
    """Issue 26: every file read by name is a regular file.  A sysfs attribute replaced by
    a FIFO (nothing ever writes it) or a link to /dev/zero is read as empty, and the scan
    finishes."""
    import os
    import threading

    from test_evdev_fakes import add_device, paths

    from mousedom.sources.discovery import scan

    add_device(tmp_path, 3, "Fine Mouse")
    add_device(tmp_path, 4, "Odd Mouse")
    attrs = tmp_path / "sys" / "class" / "input" / "event4" / "device"
    (attrs / "name").unlink()
    os.mkfifo(attrs / "name")
    (attrs / "phys").unlink()
    (attrs / "phys").symlink_to("/dev/zero")
    result = {}
    t = threading.Thread(target=lambda: result.update(s=scan(paths(tmp_path))), daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive(), "the scan blocked"
    names = sorted(d.name for d in result["s"].devices)
    assert "Fine Mouse" in names


def test_list_escapes_control_characters_of_a_devices_strings(tmp_path):
    """A device name with a newline broke the listing's layout, one with ESC sent the
    terminal an escape sequence: shown escaped, each device's lines its own."""
    from mousedom.commands.list import _text

    add_device(tmp_path, 3, "Evil\nMouse\x1b[31m", phys="usb-1\t/input0")
    text = _text(scan(paths(tmp_path)))
    assert "\x1b" not in text and "\t" not in text
    assert "Evil\\nMouse\\x1b[31m" in text and "phys     usb-1\\t/input0" in text


def test_a_device_unplugged_during_the_scan_is_not_called_closed(tmp_path, monkeypatch):
    """devtmpfs removes the node first on unplug: a scan that listed it, then found it
    gone, said "permission denied ... join group 'input'" (even to root) and doctor FAILed
    "closed to this user".  A node gone (or a link to nothing) is no device."""
    from mousedom.commands import list as listcmd
    from mousedom.sources import discovery

    add_device(tmp_path, 5, "Logitech USB Optical Mouse", phys="usb-0000:00:14.0-2/input0")
    add_device(tmp_path, 6, "Other Mouse", phys="usb-0000:00:14.0-3/input0")
    describe = discovery._describe_from_sysfs

    def unplugged_now(paths, event, node, links):
        if event == "event5" and os.path.exists(node):
            os.unlink(node)
        return describe(paths, event, node, links)

    monkeypatch.setattr(discovery, "_describe_from_sysfs", unplugged_now)
    result = discovery.scan(paths(tmp_path))
    assert [d.name for d in result.devices] == ["Other Mouse"]
    text = listcmd._text(result)
    assert "permission denied" not in text and "event5" not in text, text


def test_a_capability_mask_that_is_no_hex_is_no_traceback(tmp_path):
    """A tree given with --root (copied, hand-made) may hold anything: one device's
    capabilities/rel of 'zz' raised ValueError out of list, doctor and record, and the
    other mice went unlisted with it."""
    from mousedom.sources import discovery

    add_device(tmp_path, 3, "Broken", rel="zz")
    add_device(tmp_path, 4, "Good Mouse")
    result = discovery.scan(paths(tmp_path))
    assert [d.name for d in result.devices] == ["Good Mouse"]


def test_a_readable_device_without_a_name_shows_its_ids(tmp_path):
    """An empty sysfs name read as "(unknown: cannot open)", the ids hidden, though the
    node was readable (and the entry offered a config rule)."""
    from mousedom.commands import list as listcmd
    from mousedom.sources import discovery

    add_device(tmp_path, 2, "", vendor=0x1234, product=0xABCD, phys="usb-1/input0")
    result = discovery.scan(paths(tmp_path))
    assert result.devices and result.devices[0].readable
    text = listcmd._text(result)
    assert "(no name)" in text and "cannot open" not in text, text
    assert "1234:abcd" in text, text
