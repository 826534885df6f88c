"""`mousedom check-config` as a user runs it."""

from __future__ import annotations

import pytest
from conftest import run_mousedom


def write(tmp_path, text: str):
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    return path


def test_prints_each_mouse_and_its_source(tmp_path):
    (tmp_path / "drive.mdcap").write_bytes(b"")  # only its existence is checked here
    path = write(
        tmp_path,
        "model: diff-drive\n"
        "calibration: rig.calib.yaml\n"
        "mice:\n"
        "  floor: {cpi: 1600, mount: {x: 0.1}, serial: {port: /dev/ttyUSB0, k: 8}}\n"
        "  side: {cpi: {x: 400, y: 410}, mount: {x: -0.1, y: 0.05, yaw: 90}, flip: true,\n"
        "         replay: {file: drive.mdcap, device: sim b}}\n"
        "  usb: {cpi: 450, mount: {x: 0, y: -0.1}, evdev: {name: Logitech USB, grab: false}}\n",
    )
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == f"{path}: diff-drive model, exact integrator, 100 Hz"
    # serial: the report rate follows K (1e6 / (8 * 1250) = 100 Hz)
    assert lines[1] == (
        "  floor: cpi 1600/1600, mount (0.1, 0) m, yaw 0 deg, 100 Hz, "
        "source serial /dev/ttyUSB0 (115200 baud, k 8, sensor 1600 cpi); "
        "tracks up to 1.016 m/s, SQUAL at least 15"  # the ADNS-3080's datasheet limits
    )
    assert lines[2] == (
        "  side: cpi 400/410, mount (-0.1, 0.05) m, yaw 90 deg, flipped, 125 Hz, "
        f"source replay {tmp_path / 'drive.mdcap'} device 'sim b'"
    )
    assert "source evdev (name 'Logitech USB', not grabbed)" in lines[3]
    assert lines[4].startswith("  fault tolerance: on (false alarm 0.0001 per window")
    # Regression: nothing said whether the calibration file exists (and so is applied).
    assert lines[5] == f"  calibration: {tmp_path / 'rig.calib.yaml'} (not written yet)"
    (tmp_path / "rig.calib.yaml").write_text("mice:\n  usb: {cpi: {x: 451, y: 452}}\n")
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 0, p.stderr
    assert "usb: cpi 451/452" in p.stdout and "(applied)" in p.stdout


def test_a_missing_replay_file_is_an_error(tmp_path):
    """Regression: check-config passed a rig whose replay capture does not exist."""
    path = write(
        tmp_path,
        "mice:\n"
        "  a: {cpi: 400, mount: {x: 0.1}, replay: gone.events}\n"
        "  b: {cpi: 400, mount: {x: -0.1}, replay: gone.events}\n",
    )
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert f"mice.a.replay: {tmp_path / 'gone.events'}: capture file not found" in p.stderr


def test_mice_without_a_source_suggest_no_sources(tmp_path):
    """Regression: the error did not say that a captures-only rig is checked with
    --no-sources; with it the rig passes."""
    path = write(tmp_path, "mice:\n  a: {cpi: 400, mount: {x: 0.1}}\n  b: {cpi: 400, mount: {}}\n")
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "mice.a: says nowhere where the mouse comes from" in p.stderr
    assert "add --no-sources" in p.stderr
    assert run_mousedom("check-config", "--config", str(path), "--no-sources").returncode == 0
    # Another error is reported as it is, without the hint.
    write(tmp_path, "mice:\n  a: {cpi: zero, mount: {x: 0.1}}\n")
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and "mice.a.cpi: must be a number" in p.stderr
    assert "--no-sources" not in p.stderr


def test_missing_and_binary_config(tmp_path):
    p = run_mousedom("check-config", "--config", str(tmp_path / "nope.yaml"))
    assert p.returncode == 2 and "nope.yaml: config file not found" in p.stderr
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    p = run_mousedom("check-config", "--config", str(tmp_path / "bin.yaml"))
    assert p.returncode == 2 and "Traceback" not in p.stderr and "not UTF-8" in p.stderr


def test_every_mistake_at_once_each_on_its_own_line_with_a_suggestion(tmp_path):
    """Issue 14 item 4: a misspelt key inside a mouse (`mownt:`) was reported as
    "mice.right.mount: is required" on the mouse's line, never naming mownt; and only the
    first mistake of a file was reported."""
    path = write(
        tmp_path,
        "model: lsq\n"  # 1
        "mice:\n"  # 2
        "  left:\n"  # 3
        "    cpi: 400\n"  # 4
        "    mount: {x: 0, y: 0.1}\n"  # 5
        "    evdev: {path: /dev/input/event9}\n"  # 6
        "  right:\n"  # 7
        "    cpi: -4\n"  # 8
        "    mownt: {x: 0, y: -0.1}\n"  # 9
        "    evdev: {path: /dev/input/event8, grabb: true}\n"  # 10
        "serverr: {}\n",  # 11
    )
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    lines = p.stderr.removeprefix("mousedom: error: ").splitlines()
    assert lines == [
        f"{path}:8: mice.right.cpi: must be a positive number, got -4",
        f"{path}:9: mice.right.mownt: unknown key (did you mean mount? see docs/config.md)",
        f"{path}:10: mice.right.evdev.grabb: unknown key (did you mean grab? see docs/config.md)",
        f"{path}:11: serverr: unknown key (did you mean server? see docs/config.md)",
    ]


def test_an_empty_file_gets_a_line(tmp_path):
    path = write(tmp_path, "")
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and f"{path}:1: the file is empty" in p.stderr


def test_two_mice_on_one_device_and_absent_devices(tmp_path):
    """Two mice naming one evdev node (here through a link) are refused, as list and the
    daemon refuse them; an absent device is a note, or exit 1 with --require-devices."""
    node = tmp_path / "event9"
    node.write_text("")
    (tmp_path / "by-path").symlink_to(node)
    rig = (
        "model: lsq\nmice:\n"
        "  a: {{cpi: 400, mount: {{x: 0, y: 0.1}}, evdev: {{path: {a}}}}}\n"
        "  b: {{cpi: 400, mount: {{x: 0, y: -0.1}}, evdev: {{path: {b}}}}}\n"
    )
    path = write(tmp_path, rig.format(a=node, b=tmp_path / "by-path"))
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 2 and "mice a and b name one device" in p.stderr
    path = write(tmp_path, rig.format(a=node, b=tmp_path / "event8"))
    p = run_mousedom("check-config", "--config", str(path))
    assert p.returncode == 0, p.stderr
    assert f"note: mice.b: {tmp_path / 'event8'} does not exist on this machine" in p.stdout
    assert "mice.a" not in p.stdout.split("note:", 1)[1]
    p = run_mousedom("check-config", "--config", str(path), "--require-devices")
    assert p.returncode == 1 and "1 device(s) absent" in p.stderr


def test_the_shipped_example_leaves_the_adns_rate_to_k():
    """docs/adns-protocol.md: leave report_hz of the downsampler derived from K."""
    import yaml
    from conftest import REPO

    doc = yaml.safe_load((REPO / "config" / "mousedom.yaml").read_text())
    serial = [m for m in doc["mice"].values() if "serial" in m]
    assert serial and all("report_hz" not in m for m in serial)
    assert "config/mousedom.yaml" not in (REPO / ".gitignore").read_text()


@pytest.mark.parametrize(
    "text, words",
    [
        ("mice: " + "[" * 3000 + "]" * 3000 + "\n", "nest"),  # RecursionError once
        ("rate_hz: " + "9" * 400 + "\nmice: {}\n", "integer of 400"),  # OverflowError once
        ("mice:\n  a: {cpi: " + "9" * 5000 + "}\n", "integer of 5000"),  # ValueError once
        (
            "a: &a [x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
            + "".join(
                f"c{i}: &c{i} [" + ", ".join(["*b" if i == 0 else f"*c{i - 1}"] * 10) + "]\n"
                for i in range(6)
            ),
            "aliases expand",
        ),  # fmt: skip
        ('calibration: "\\0"\nmice: {a: {cpi: 1, mount: {x: 0, y: 0}}}\n', "NUL"),
    ],
    ids=["deep", "overflow", "long-int", "alias-bomb", "nul"],
)
def test_configs_that_once_gave_tracebacks_are_one_error_each(tmp_path, text, words):
    """Issue 11 item 5: check-config printed tracebacks for these configs."""
    path = write(tmp_path, text)
    p = run_mousedom("check-config", "--config", str(path), "--no-sources")
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.startswith(f"mousedom: error: {path}:") and words in p.stderr, p.stderr


def test_a_misspelt_key_in_the_calibration_file_gets_a_suggestion(tmp_path):
    (tmp_path / "rig.calib.yaml").write_text("mice:\n  a:\n    cpj: 500\n")
    path = write(
        tmp_path,
        "calibration: rig.calib.yaml\nmice:\n  a: {cpi: 400, mount: {x: 0, y: 0.1}}\n"
        "  b: {cpi: 400, mount: {x: 0, y: -0.1}}\n",
    )
    p = run_mousedom("check-config", "--config", str(path), "--no-sources")
    assert p.returncode == 2
    assert "rig.calib.yaml:3: mice.a.cpj: unknown key (did you mean cpi?" in p.stderr
