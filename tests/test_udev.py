"""udev/72-mousedom.rules: well-formed, and it gives what the example config expects.

udev itself is not in this container (no /dev/input, no udevd), so the rules are parsed
here with the syntax of udev(7); where ``udevadm verify`` exists (systemd >= 254) it
checks them too.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from mousedom.config import load_config

ROOT = Path(__file__).resolve().parent.parent
RULES = ROOT / "udev" / "72-mousedom.rules"
EXAMPLE = ROOT / "config" / "mousedom.yaml"

# udev(7): KEY[{attr}] OP "value"; match keys take == and !=, the rest assign.
TOKEN = re.compile(r'\s*([A-Z_]+)(?:\{([^}]*)\})?\s*(==|!=|\+=|-=|:=|=)\s*"((?:[^"\\]|\\.)*)"\s*')
MATCH_KEYS = {"ACTION", "KERNEL", "SUBSYSTEM", "SUBSYSTEMS", "ATTRS", "ATTR", "ENV", "TAG"}
ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "OWNER", "ENV", "TAG", "GOTO", "LABEL", "RUN"}


def parse_rules(text: str) -> list[list[tuple[str, str | None, str, str]]]:
    rules = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens, pos = [], 0
        while pos < len(line):
            m = TOKEN.match(line, pos)
            assert m, f"{RULES.name}:{number}: cannot parse at column {pos + 1}: {line[pos:]!r}"
            key, attr, op, value = m.groups()
            if op in ("==", "!="):
                assert key in MATCH_KEYS, f"{RULES.name}:{number}: {key} cannot be matched"
            else:
                assert key in ASSIGN_KEYS, f"{RULES.name}:{number}: {key} cannot be assigned"
            tokens.append((key, attr, op, value))
            pos = m.end()
            if pos < len(line):
                assert line[pos] == ",", f"{RULES.name}:{number}: expected ',' at {pos + 1}"
                pos += 1
        rules.append(tokens)
    return rules


def test_rules_parse_and_every_goto_has_its_label():
    rules = parse_rules(RULES.read_text())
    labels = {v for r in rules for k, _, _, v in r if k == "LABEL"}
    gotos = {v for r in rules for k, _, _, v in r if k == "GOTO"}
    assert gotos <= labels, gotos - labels


def test_parser_rejects_broken_rules():
    import pytest

    for bad in ('KERNEL="event*"', 'SYMLINK=="x"', 'ENV{A}="1" GROUP="input"', "MODE=0640"):
        with pytest.raises(AssertionError):
            parse_rules(bad)


def test_mice_get_names_groups_and_the_desktop_ignores_them():
    text = RULES.read_text()
    rules = parse_rules(text)
    flat = [t for r in rules for t in r]
    assert ("ENV", "LIBINPUT_IGNORE_DEVICE", "=", "1") in flat
    assert ("SYMLINK", None, "+=", "input/mousedom-$env{MOUSEDOM_NAME}") in flat
    assert ("GROUP", None, "=", "input") in flat
    assert ("TAG", None, "-=", "uaccess") in flat
    named = {v for k, a, op, v in flat if k == "ENV" and a == "MOUSEDOM_NAME" and op == "="}
    serial = [r for r in rules if ("SYMLINK", None, "+=", "mousedom-adns") in r]
    assert len(serial) == 1 and ("GROUP", None, "=", "dialout") in serial[0]

    # The example config reads exactly the devices that the rules name.
    config = load_config(EXAMPLE)
    evdev_paths = {m.evdev.path for m in config.mice if m.evdev}
    assert evdev_paths == {f"/dev/input/mousedom-{name}" for name in named}
    ports = {m.serial.port for m in config.mice if m.serial}
    assert ports == {"/dev/mousedom-adns"}


def _udevadm() -> str:
    """A udevadm with ``verify``: MOUSEDOM_UDEVADM (CI unpacks one from Debian's backports,
    scripts/udevadm_tool.sh), else the machine's.  In CI a missing one is a failure."""
    tool = os.environ.get("MOUSEDOM_UDEVADM") or shutil.which("udevadm")
    required = bool(os.environ.get("CI") or os.environ.get("MOUSEDOM_REQUIRE_SYSTEMD"))
    help_text = (
        ""
        if tool is None
        else subprocess.run([tool, "--help"], capture_output=True, text=True).stdout
    )
    if "verify" not in help_text:
        why = (
            "udevadm is not installed"
            if tool is None
            else f"{tool} has no 'verify' (systemd < 254)"
        )
        if required:
            pytest.fail(f"{why}: CI runs bash scripts/udevadm_tool.sh for one")
        pytest.skip(f"{why} (the rules are still parsed by the tests above)")
    assert tool is not None
    return tool


def test_udevadm_verify():
    """``udevadm verify`` (systemd >= 254), style included.  Group names are not resolved:
    the groups are the robot's, not this machine's (the next test ties them to the unit)."""
    out = subprocess.run(
        [_udevadm(), "verify", "--resolve-names=never", str(RULES)], capture_output=True, text=True
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Success: 1" in out.stdout, out.stdout


def test_udevadm_verify_fails_on_a_broken_rule(tmp_path):
    """The verify above can fail: a rule with a typo'd key and one with an unknown operator."""
    for bad in ('SUBSYTEM=="input", GOTO="x"\nLABEL="x"\n', 'KERNEL=~"event*"\n'):
        rules = tmp_path / "99-bad.rules"
        rules.write_text(RULES.read_text() + bad)
        out = subprocess.run(
            [_udevadm(), "verify", "--resolve-names=never", str(rules)],
            capture_output=True,
            text=True,
        )
        assert out.returncode != 0, (bad, out.stdout + out.stderr)


def test_every_group_the_rules_give_devices_to_is_the_daemons():
    """A device given to a group the daemon's unit is not in is a refusal at open on the
    robot (as root here, nothing would say so): each GROUP is the unit's Group= or one of
    its SupplementaryGroups=, and the unit's own group is made by the sysusers snippet."""
    unit = (ROOT / "config" / "systemd" / "mousedom.service").read_text()
    keys: dict[str, str] = {}
    for line in unit.splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            k, v = line.split("=", 1)
            keys[k.strip()] = v.strip()
    joined = {keys["Group"], *keys.get("SupplementaryGroups", "").split()}
    groups = {v for rule in parse_rules(RULES.read_text()) for k, _, _, v in rule if k == "GROUP"}
    assert groups and groups <= joined, (groups, joined)
    sysusers = (ROOT / "config" / "systemd" / "mousedom.sysusers").read_text().split()
    assert sysusers[sysusers.index("u") + 1] == keys["Group"] == keys["User"]
    chgrp = set(re.findall(r"chgrp (\w+)", RULES.read_text()))
    assert chgrp and chgrp <= joined, chgrp


def test_every_attribute_the_gyro_source_writes_is_given_to_the_group(tmp_path):
    """The daemon runs as its own user: an attribute it writes at a gyro's open that the
    rule leaves root's is a refusal on the robot (here, as root, nothing would say so).
    A device whose every attribute needs a write (clock, rate, buffer length and
    watermark, an element someone else enabled): each one written is in the rule's list."""
    import fnmatch

    from iio_fakes import add_gyro

    from mousedom.config import GyroConfig
    from mousedom.sources.iio import GyroSource
    from mousedom.sources.iio_sysfs import IioPaths

    sysdir = add_gyro(tmp_path)
    (sysdir / "scan_elements" / "in_accel_x_en").write_text("1\n")
    (sysdir / "buffer" / "watermark").write_text("64\n")
    runs = [v for rule in parse_rules(RULES.read_text()) for k, _, _, v in rule if k == "RUN"]
    listed = next(r for r in runs if "current_timestamp_clock" in r)
    names = re.search(r"for f in (.*?); do", listed)
    assert names, listed
    patterns = names.group(1).split()
    src = GyroSource(GyroConfig(name="mpu6050", sample_hz=200), IioPaths.under(str(tmp_path)))
    src.open()
    try:
        written = [str(path.relative_to(sysdir)) for path, _ in src.sysfs.undo]
    finally:
        src.close()
    assert "buffer/watermark" in written and "buffer/enable" in written, written
    for w in written:
        assert any(fnmatch.fnmatch(w, p) for p in patterns), (w, patterns)


def test_the_rules_sort_where_taking_the_uaccess_tag_off_still_counts():
    """systemd's 70-uaccess.rules and 71-seat.rules add the uaccess and seat tags; its
    73-seat-late.rules queues the ACL for a device tagged uaccess then.  As 99-mousedom.rules
    the TAG-="uaccess" came after that, and the logged-in user kept an ACL on a mouse an
    earlier rule had tagged.  The file sorts between them."""
    udev = Path(__file__).resolve().parent.parent / "udev"
    (name,) = [p.name for p in udev.glob("*.rules")]
    assert "70-uaccess.rules" < "71-seat.rules" < name < "73-seat-late.rules", name
    assert 'TAG-="uaccess"' in (udev / name).read_text()
