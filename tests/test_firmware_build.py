"""The firmware builds from a clean tree, fits in half the ATmega8, uses no heap, and its
pure modules (CRC, COBS framing, packets, accumulator, clock maths) pass their host-gcc
unit tests; the simulated ADNS-3080 used by test_firmware_sim.py passes its own.

Needs gcc-avr, avr-libc, simavr and libsimavr-dev (firmware/install-toolchain.sh).
Without them these tests skip, except in CI or with MOUSEDOM_REQUIRE_FIRMWARE=1, where
they fail."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parent.parent / "firmware"
NEEDS = {
    "avr-gcc": "gcc-avr",
    "avr-size": "binutils-avr",
    "avr-nm": "binutils-avr",
    "gcc": "gcc",
    "make": "make",
}
FILES = {
    "/usr/lib/avr/include/avr/io.h": "avr-libc",
    "/usr/include/simavr/sim_avr.h": "libsimavr-dev",
}


def require_toolchain() -> None:
    missing = sorted(
        {pkg for tool, pkg in NEEDS.items() if shutil.which(tool) is None}
        | {pkg for path, pkg in FILES.items() if not os.path.exists(path)}
    )
    if not missing:
        return
    msg = (
        f"firmware toolchain missing ({', '.join(missing)}): run firmware/install-toolchain.sh "
        f"or apt-get install {' '.join(missing)}"
    )
    if os.environ.get("MOUSEDOM_REQUIRE_FIRMWARE") == "1" or os.environ.get("CI"):
        pytest.fail(msg)
    pytest.skip(msg)


def make(build: Path, *targets: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["make", "-C", str(FIRMWARE), f"BUILD={build}", *targets],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    """A clean build directory, as on a fresh checkout."""
    require_toolchain()
    out = tmp_path_factory.mktemp("fwbuild")
    r = make(out, "all")
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def test_host_unit_tests(build):
    r = make(build, "test")
    assert r.returncode == 0, r.stdout + r.stderr
    m = re.search(r"test_host: (\d+) checks, (\d+) failures", r.stdout)
    assert m and int(m.group(1)) > 1000 and m.group(2) == "0", r.stdout


def test_size_within_half_of_the_atmega8(build):
    r = make(build, "size")
    assert r.returncode == 0, r.stdout + r.stderr
    flash = int(re.search(r"flash: (\d+) bytes", r.stdout).group(1))
    sram = int(re.search(r"sram:\s+(\d+) bytes", r.stdout).group(1))
    assert 1000 < flash <= 4096 and 50 < sram <= 512, r.stdout


def test_no_dynamic_memory(build):
    syms = subprocess.run(
        ["avr-nm", str(build / "downsampler.elf")], capture_output=True, text=True, check=True
    ).stdout
    names = {line.split()[-1] for line in syms.splitlines() if line.strip()}
    assert not names & {"malloc", "free", "calloc", "realloc", "__brkval"}


def test_size_target_fails_over_budget(build):
    """The budget check can fail: with a limit below the real size, make size refuses."""
    r = subprocess.run(
        ["make", "-C", str(FIRMWARE), f"BUILD={build}", "FLASH_MAX=100", "size"],
        capture_output=True,
        text=True,
    )
    assert r.returncode != 0 and "over budget" in r.stdout + r.stderr


def test_sensor_model_unit_tests(build):
    r = make(build, "sim-tools")
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([str(build / "test_sensor")], capture_output=True, text=True)
    assert r.returncode == 0 and " 0 failures" in r.stdout, r.stdout + r.stderr


def test_missing_toolchain_skips_locally_and_fails_in_ci(monkeypatch):
    """Without the tools: a skip naming what to install, unless CI or
    MOUSEDOM_REQUIRE_FIRMWARE=1 asks for the firmware tests to run, then a failure."""
    monkeypatch.setattr(shutil, "which", lambda tool: None)
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv("MOUSEDOM_REQUIRE_FIRMWARE", raising=False)
    with pytest.raises(pytest.skip.Exception, match="install-toolchain.sh.*gcc-avr"):
        require_toolchain()
    monkeypatch.setenv("MOUSEDOM_REQUIRE_FIRMWARE", "1")
    with pytest.raises(pytest.fail.Exception, match="gcc-avr"):
        require_toolchain()
    monkeypatch.delenv("MOUSEDOM_REQUIRE_FIRMWARE")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception):
        require_toolchain()


def test_install_script_installs_every_tool_the_tests_need():
    """Regression: install-toolchain.sh (what CI runs) left out make and the host gcc that
    `make test` and the simavr harness need, so a slim CI image failed these tests."""
    script = (FIRMWARE / "install-toolchain.sh").read_text()
    listed = re.search(r'^PACKAGES="([^"]*)"', script, re.M)
    assert listed, "no PACKAGES= line in install-toolchain.sh"
    needed = set(NEEDS.values()) | set(FILES.values()) | {"libc6-dev"}
    assert needed <= set(listed.group(1).split()), needed - set(listed.group(1).split())


def test_simulator_help(build):
    """Regression: `adns_sim --help` tried to load a firmware file called --help."""
    r = make(build, "sim-tools")
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([str(build / "adns_sim"), "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "--seg T:VX:VY" in r.stdout and "SUMMARY" in r.stdout
    r = subprocess.run([str(build / "adns_sim")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("usage: adns_sim FIRMWARE.elf")
