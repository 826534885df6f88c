"""`mousedom check-config` as a user runs it."""

from __future__ import annotations

import pytest
from conftest import run_mousedom


def write(tmp_path, text: str):
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    return path


def capture(path, devices: dict[str, str | None], gyro: bool = False):
    """A small native capture: a device named ``name`` for each mouse ``mouse`` (None: no
    mouse of its own) with two reports, and an IIO gyro with two samples."""
    import numpy as np

    from mousedom.capture import DeviceInfo, NativeWriter

    devs = [DeviceInfo(name=name, mouse=mouse) for name, mouse in devices.items()]
    if gyro:
        devs.append(DeviceInfo(name="mpu6050", kind="iio", rel_xy=False))
    with NativeWriter(path, devs) as w:
        for i in range(len(devices)):
            w.motion(i, np.array([1.0, 2.0]), np.array([1, 1]), np.array([0, 0]))
        if gyro:
            w.gyro(len(devices), np.array([1.0, 2.0]), np.array([0.0, 0.1]))
    return path


def test_prints_each_mouse_and_its_source(tmp_path):
    capture(tmp_path / "drive.mdcap", {"sim a": None, "sim b": None})
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
    gone = tmp_path / "gone.events"
    assert f"rig.yaml:2: mice.a.replay: {gone}: capture file not found" in p.stderr


@pytest.mark.parametrize("device, words", [
    ("abc", "rig.yaml:4: mice.a.replay.device: no device 'abc' in"),
    (None, "rig.yaml:4: mice.a.replay: 0 devices of"),
])  # fmt: skip
def test_a_replay_device_not_in_its_capture_is_an_error_naming_the_config_line(
    tmp_path, device, words
):
    """check-config passed a replay.device its capture does not hold (exit 0, "it would
    run"), and replay then refused it naming the capture, not the config's line."""
    capture(tmp_path / "cap.mdcap", {"sim x": None, "sim y": None})
    ref = "{file: cap.mdcap}" if device is None else f"{{file: cap.mdcap, device: {device}}}"
    path = write(
        tmp_path,
        "rate_hz: 100\nmice:\n  a:\n"
        f"    replay: {ref}\n"
        "    cpi: 400\n    mount: {x: 0.1}\n"
        "  b: {cpi: 400, mount: {x: -0.1, y: 0.1}, replay: {file: cap.mdcap, device: sim y}}\n"
        "  c: {cpi: 400, mount: {x: -0.1, y: -0.1}, replay: {file: cap.mdcap, device: sim x}}\n",
    )
    for command in (("check-config",), ("replay", "-o", str(tmp_path / "o.csv"))):
        p = run_mousedom(*command, "--config", str(path))
        assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
        assert words in p.stderr, p.stderr


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


def _notes(tmp_path, model: str, mounts: dict[str, tuple[float, float]], extra: str = ""):
    mice = "".join(
        f"  {n}: {{cpi: 800, mount: {{x: {x}, y: {y}}}}}\n" for n, (x, y) in mounts.items()
    )
    path = write(tmp_path, f"model: {model}\n{extra}mice:\n{mice}")
    p = run_mousedom("check-config", "--config", str(path), "--no-sources")
    assert p.returncode == 0, p.stderr  # notes, not errors
    return [ln.removeprefix("  note: ") for ln in p.stdout.splitlines() if "note:" in ln]


AXLE = {"left": (0, 0.1), "right": (0, -0.1)}


def test_check_config_notes_what_the_layout_cannot_see(tmp_path):
    """Issue 31 item 5: two mice on the axle cannot see a lift (it reads as a pivot about
    the other mouse); two mice check each other only along the line joining them; one
    mouse has no redundancy; three need no note."""
    notes = _notes(tmp_path, "diff-drive", AXLE)
    assert notes == [
        "mice left and right: 2 redundant readings (4 readings, 2 unknowns): their motion "
        "along the line joining them must agree and the axle must not slide sideways; a fault "
        "shows only as a breach of these, and which of the two is at fault cannot be told",
        "mice left and right are both on the axle (x = 0): every motion of a differential "
        "drive moves them across the line joining them, so a lifted mouse reads as a pivot "
        "about the other, a legal motion: a lift is never detected (a mouse off the axle "
        "would see it)",
    ]
    for model in ("lsq", "bonarini"):  # any model: across the travel, straight driving hides it
        notes = _notes(tmp_path, model, AXLE)
        assert len(notes) == 2 and notes[0].startswith("mice left and right: 1 redundant reading")
        assert "which of the two is at fault cannot be told" in notes[0]
        assert notes[1].startswith("mice left and right lie on a line across the direction of "
                                   "travel (within 11 degrees): while the robot drives straight, "
                                   "a lifted mouse reads as a pivot about the other")  # fmt: skip
    # One in front of the other: driving ahead moves them along their line, a lift shows.
    notes = _notes(tmp_path, "lsq", {"front": (0.1, 0), "back": (-0.1, 0)})
    assert len(notes) == 1 and "a lifted mouse only while it moves along it" in notes[0]
    # A differential drive's pair off the axle: a pivot about a mouse is not legal there.
    notes = _notes(tmp_path, "diff-drive", {"a": (0.1, 0.1), "b": (0.1, -0.1)})
    assert len(notes) == 1 and "axle must not slide sideways" in notes[0]
    assert _notes(tmp_path, "diff-drive", {"solo": (0.1, 0)}) == [
        "mouse solo alone: no redundant reading (2 readings, 2 unknowns), so no fault shows in "
        "the readings; only the sensor itself can flag one (an ADNS-3080's SQUAL and overflow, "
        "min_squal, max_speed)"
    ]
    three = {"f": (0.15, 0), "l": (-0.075, 0.13), "r": (-0.075, -0.13)}
    assert _notes(tmp_path, "lsq", three) == [] and _notes(tmp_path, "diff-drive", three) == []
    # Three near a line across the robot (a review's rig: a healthy end mouse excluded for
    # a lifted middle one in 8 of 20 drives, metres off): said; 4 cm off the line, not.
    line = {"l": (0.01, 0.15), "m": (-0.02, 0.0), "r": (0.015, -0.15)}
    notes = _notes(tmp_path, "lsq", line)
    assert len(notes) == 1 and notes[0].startswith(
        "mice l, m, r lie near one line (each within 22 mm of it over 300 mm)"
    ), notes
    assert "told only once the robot moves along the line" in notes[0]
    assert _notes(tmp_path, "lsq", {**line, "m": (-0.08, 0.0)}) == []
    # With the fault test off nothing is tested: no notes about what it sees.
    assert _notes(tmp_path, "diff-drive", AXLE, "robust: false\n") == []


def test_blind_spots_tolerances():
    """How near the layouts of the notes a pair may be and still hide a lift."""
    import math

    from mousedom.observability import across_tolerance, blind_spots

    tol = across_tolerance(0.05, 1e-4)
    assert math.degrees(math.asin(tol)) == pytest.approx(11.2, abs=0.1)
    for deg, hidden in ((0, True), (5, True), (10, True), (15, False), (45, False)):
        s, c = 0.1 * math.sin(math.radians(deg)), 0.1 * math.cos(math.radians(deg))
        notes = blind_spots("lsq", [("a", s, c), ("b", -s, -c)])
        assert any("across the direction of travel" in n for n in notes) == hidden, deg
    # a noisier rig hides more
    notes = blind_spots("lsq", [("a", 0.05, 0.1), ("b", -0.05, -0.1)], relative_noise=0.2)
    assert any("within 51 degrees" in n for n in notes)
    for x, hidden in ((0.0, True), (0.002, True), (0.01, False), (0.1, False)):
        notes = blind_spots("diff-drive", [("a", x, 0.1), ("b", x, -0.1)])
        assert any("both on the axle" in n for n in notes) == hidden, x
    assert blind_spots("diff-drive", [("a", 0.1, 0.0), ("b", 0.1, 0.0)]) == [
        "mice a and b sit at one point: their readings must be equal; a fault shows only as a "
        "difference, and which of the two is at fault cannot be told"
    ]


@pytest.mark.parametrize(
    ("model", "mounts", "seen"),
    [
        ("lsq", ((0.0, 0.1), (0.0, -0.1)), False),  # across the travel: the note's blind spot
        ("diff-drive", ((0.0, 0.1), (0.0, -0.1)), False),  # on the axle: likewise
        ("lsq", ((0.1, 0.0), (-0.1, 0.0)), True),  # along the travel: no such note
        ("diff-drive", ((0.1, 0.1), (0.1, -0.1)), True),  # off the axle: no such note
    ],
)
def test_the_notes_say_what_the_engine_sees(model, mounts, seen):
    """The notes against the fusion: a mouse lifted for 1.5 s of a straight drive is
    flagged (inconsistent windows, or a mouse not tracking) where no note says it hides."""
    import dataclasses

    import numpy as np

    from mousedom.fusion import sim
    from mousedom.observability import blind_spots

    mice = tuple(sim.SimMouse(n, x, y, cpi_x=800, cpi_y=800, report_hz=500, noise=0.3)
                 for n, (x, y) in zip("ab", mounts, strict=True))  # fmt: skip
    rig = sim.Rig(mice, model=model)
    lifted = dataclasses.replace(
        rig, mice=(mice[0], dataclasses.replace(mice[1], lost=((1.0, 2.5),)))
    )
    b, _ = sim.run_tracker(
        sim.simulate(lifted, sim.straight(0.7, 0.2), seed=1), sim.rig_config(rig)
    )
    w = (b.t > 1.05) & (b.t < 2.5)
    flagged = float(np.mean(~b.consistent[w] | (b.state[w] != 0).any(axis=1)))
    notes = blind_spots(model, [(m.name, m.x, m.y) for m in mice])
    hides = any("lifted mouse reads as a pivot" in n for n in notes)
    assert hides == (not seen)
    assert flagged > 0.9 if seen else flagged < 0.1, flagged


_TWO_MICE = (
    "mice:\n"
    "  a: {cpi: 800, mount: {x: 0.1, y: 0}, replay: {capture}}\n"
    "  b: {cpi: 800, mount: {x: -0.1, y: 0}, replay: {capture}}\n"
)


@pytest.mark.parametrize("gyro, said", [
    ("{name: mpu6050, path: /nonexistent/iio:device0, axis: x, sign: -1, sample_hz: 200}",
     "gyro: IIO device (path '/nonexistent/iio:device0', name 'mpu6050'), axis -x along "
     "body z, 200 Hz, noise 8.72665e-05 rad/s/sqrt(Hz), heading from the gyro and the mice"),
    ("{name: bmi160, use: gyro, noise: 1e-4}",
     "gyro: IIO device (name 'bmi160'), axis +z along body z, the device's own rate, noise "
     "0.0001 rad/s/sqrt(Hz), heading from the gyro"),
    ("{ros2: {topic: /imu/data, domain_id: 7}, use: mice}",
     "gyro: ROS 2 topic /imu/data (domain 7, stamps system), axis +z along body z"),
    ("{replay: {gyro_capture}}", "gyro: replay {gyro_capture}, axis +z"),
])  # fmt: skip
def test_the_gyro_is_said_with_its_source_axis_rate_and_use(tmp_path, gyro, said):
    """check-config said nothing of a rig's gyro: where its rate comes from, its axis and
    sign, its rate and noise and what the heading is taken from are a line of their own;
    an IIO path absent here is a note, and an absent device with --require-devices, or a
    gyro capture that is not there, an error."""
    mice = capture(tmp_path / "run.mdcap", {"sim a": "a", "sim b": "b"})
    gyro_capture = capture(tmp_path / "gyro.mdcap", {}, gyro=True)
    cfg = tmp_path / "rig.yaml"
    gyro_text = gyro.replace("{gyro_capture}", str(gyro_capture))
    cfg.write_text(_TWO_MICE.replace("{capture}", str(mice)) + f"gyro: {gyro_text}\n")
    p = run_mousedom("check-config", "--config", str(cfg))
    assert p.returncode == 0, p.stderr
    gyro_lines = [ln for ln in p.stdout.splitlines() if ln.startswith("  gyro: ")]
    assert len(gyro_lines) == 1, p.stdout
    assert said.replace("{gyro_capture}", str(gyro_capture)) in gyro_lines[0]
    absent = "/nonexistent" in gyro
    assert ("note: gyro: /nonexistent/iio:device0 does not exist" in p.stdout) == absent
    p = run_mousedom("check-config", "--config", str(cfg), "--require-devices")
    assert p.returncode == (1 if absent else 0), p.stderr
    if "replay" in gyro:
        gyro_capture.unlink()
        p = run_mousedom("check-config", "--config", str(cfg))
        assert p.returncode != 0
        assert f"gyro.replay: {gyro_capture}: capture file not found" in p.stderr
