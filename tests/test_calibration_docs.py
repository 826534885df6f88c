"""docs/calibration.md's examples run as written on the bundled samples (issue 29 item 4).

The samples (mousedom/data/cal-*) are a simulated rig with known truth, made by
scripts/make_calibration_samples.py.  Here: the script makes the same files again; the
docs' setup line copies them into an empty directory; every ``$ mousedom ...`` line of the
docs' text blocks runs there, in the docs' order (a ``--write`` example changes what
follows it), exits 0 and prints what the docs show, figure by figure within the printed
rounding; and the figures are near the truth the script knows.
"""

from __future__ import annotations

import importlib.util
import math
import os
import re
import shlex
import subprocess
import sys

import pytest
from conftest import REPO, mousedom_env

DOC = REPO / "docs" / "calibration.md"
DATA = REPO / "mousedom" / "data"
SCRIPT = REPO / "scripts" / "make_calibration_samples.py"
MAX_SAMPLE_BYTES = 64_000  # "small": tens of kB each


def _samples_module():
    spec = importlib.util.spec_from_file_location("make_calibration_samples", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


GEN = _samples_module()
TRUTH, ROUGH = GEN.TRUTH, GEN.ROUGH


# --------------------------------------------------------------------------- the docs


def _text_blocks(text: str) -> list[list[str]]:
    blocks, block = [], None
    for line in text.splitlines():
        if block is None:
            if line.strip() == "```text":
                block = []
        elif line.strip() == "```":
            blocks.append(block)
            block = None
        else:
            block.append(line)
    return blocks


def _examples() -> list[tuple[str, list[str]]]:
    """(command, the output shown under it) for every ``$ `` line of a text block; a block
    that shows no command (a synopsis, a file) is no example."""
    out: list[tuple[str, list[str]]] = []
    for block in _text_blocks(DOC.read_text()):
        if not block or not block[0].startswith("$ "):
            assert not any(ln.startswith("$ ") for ln in block), block  # output of what?
            continue
        for line in block:
            if line.startswith("$ "):
                out.append((line[2:], []))
            else:
                out[-1][1].append(line)
    return out


EXAMPLES = _examples()
SETUP = [c for c, _ in EXAMPLES if c.startswith("cp ")]
COMMANDS = [(c, shown) for c, shown in EXAMPLES if c.startswith("mousedom ")]

NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _resolution(text: str) -> float:
    """One unit of the last printed digit of a number as printed ("8.1e-05": 1e-06)."""
    mantissa, _, exponent = text.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def _line_matches(shown: str, got: str) -> str | None:
    """None when ``got`` is the line the docs show: the same words, any run of spaces for a
    run of spaces, ``...`` for any text, and each figure within one unit of its last
    printed digit (a last digit may round the other way on another machine); else why not."""
    pattern, figures = "", []
    for k, piece in enumerate(shown.strip().split("...")):
        if k:
            pattern += ".*?"
        at = 0
        for m in NUMBER.finditer(piece):
            pattern += _words(piece[at : m.start()]) + f"({NUMBER.pattern})"
            figures.append(m.group())
            at = m.end()
        pattern += _words(piece[at:])
    found = re.fullmatch(pattern, got.strip())
    if not found:
        return "the words differ"
    for want, have in zip(figures, found.groups(), strict=True):
        if abs(float(want) - float(have)) > 1.01 * _resolution(want):
            return f"{have} where the docs show {want}"
    return None


def _words(text: str) -> str:
    return r"\s+".join(re.escape(w) for w in re.split(r"\s+", text)) if text.strip() else (
        r"\s*" if text else ""
    )  # fmt: skip


# --------------------------------------------------------------------------- the samples


def test_the_samples_are_made_again_the_same_and_are_small(tmp_path):
    made = GEN.make(tmp_path, umbmark=False)
    shipped = {p.name for p in DATA.glob("cal-*")}
    assert {p.name for p in made} | {"cal-umbmark.csv", "cal-umbmark-after.csv"} == shipped, (
        "run scripts/make_calibration_samples.py"
    )
    for name in shipped:
        assert (DATA / name).stat().st_size <= MAX_SAMPLE_BYTES, name
    for p in made:
        assert (DATA / p.name).read_bytes() == p.read_bytes(), (
            f"{p.name} differs from what scripts/make_calibration_samples.py makes"
        )


@pytest.mark.parametrize(("name", "mice"), [("cal-umbmark.csv", "ROUGH"),
                                            ("cal-umbmark-after.csv", "TRUTH")])  # fmt: skip
def test_the_umbmark_runs_are_made_again_the_same(name, mice):
    """The first square each way (all ten take seconds): rows of fused odometry, so within
    half a millimetre, not byte for byte (a change to the fusion may move the last digits)."""
    rows = (DATA / name).read_text().splitlines()
    assert rows[0] == GEN.HEADER and len(rows) == 1 + 2 * GEN.SQUARES
    shipped = [rows[1], rows[1 + GEN.SQUARES]]
    again = GEN.umbmark_rows(getattr(GEN, mice), squares=1)
    for a, b in zip(shipped, again, strict=True):
        d1, *e1 = a.split(",")
        d2, *e2 = b.split(",")
        assert d1 == d2, (a, b)
        assert max(abs(float(x) - float(y)) for x, y in zip(e1, e2, strict=True)) < 5e-4, (a, b)


def test_the_docs_have_the_setup_and_an_example_of_every_procedure():
    assert len(SETUP) == 1, SETUP
    said = " ".join(c for c, _ in COMMANDS)
    for what in ("calibrate cpi", "calibrate scales", "calibrate distance", "calibrate mounts",
                 "umbmark cal-umbmark.csv", "--json", "--write"):  # fmt: skip
        assert what in said, what
    for command, shown in COMMANDS:
        assert shown, f"no output shown for: {command}"
    for name in re.findall(r"cal-[\w.-]+", said):  # every file named is shipped or written
        assert (DATA / name).exists() or name.endswith(".calib.yaml"), name


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> list[tuple[str, list[str], subprocess.CompletedProcess]]:
    """Each example run in the docs' order, in an empty directory the docs' own setup
    line filled (with this interpreter for its ``python3``)."""
    here = tmp_path_factory.mktemp("calibration-docs")
    env = mousedom_env(PYTHONUNBUFFERED="1")  # stdout and stderr in order, as on a terminal
    setup = SETUP[0].replace("python3", shlex.quote(sys.executable))
    done = subprocess.run(["bash", "-c", setup], cwd=here, env=env, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0, done.stderr
    copied = sorted(p.name for p in here.iterdir())
    assert copied == sorted(p.name for p in DATA.glob("cal-*")), copied
    # Only a --write changes what the commands after it see: the others run side by side
    # (seconds saved), each --write alone after everything before it.
    out = []
    phase: list[tuple[str, list[str], subprocess.Popen]] = []

    def finish() -> None:
        for command, shown, child in phase:
            stdout, _ = child.communicate(timeout=60)
            out.append((command, shown, subprocess.CompletedProcess(
                child.args, child.returncode, stdout)))  # fmt: skip
        phase.clear()

    for command, shown in COMMANDS:
        writes = "--write" in shlex.split(command)
        if writes:
            finish()
        child = subprocess.Popen([sys.executable, "-m", *shlex.split(command)], cwd=here,
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True)  # fmt: skip
        phase.append((command, shown, child))
        if writes:
            finish()
    finish()
    return out


def test_every_example_runs_and_prints_what_the_docs_show(ran):
    for command, shown, proc in ran:
        assert proc.returncode == 0, (command, proc.stdout)
        assert "Traceback" not in proc.stdout
        got = proc.stdout.rstrip("\n").splitlines()
        assert len(got) == len(shown), (command, "\n".join(got))
        for k, (want, have) in enumerate(zip(shown, got, strict=True)):
            why = _line_matches(want, have)
            assert why is None, f"{command}\nline {k + 1}: {why}\n docs: {want}\n  got: {have}"


def _output(ran, *words: str) -> str:
    hits = [p.stdout for c, _, p in ran if all(w in c.split() for w in words)]
    assert hits, words
    return hits[0]


def test_the_results_are_near_the_truth(ran):
    # CPI: each mouse's within 0.5 % of its true one.
    text = _output(ran, "cpi")
    found = dict(re.findall(r"^(\w+): cpi y = ([\d.]+)", text, re.M))
    assert set(found) == set(TRUTH)
    for name, cpi in found.items():
        assert float(cpi) == pytest.approx(TRUTH[name].cpi, rel=5e-3), name
    # Scales: the CPI the others imply for the one mouse that is off, within 0.5 %; the
    # others unchanged, and truly as configured.
    text = _output(ran, "scales")
    implied = dict(re.findall(r"^(\w+) .* ([\d.]+), [\d.]+$", text, re.M))
    assert set(implied) == {"front"}
    assert float(implied["front"]) == pytest.approx(TRUTH["front"].cpi, rel=5e-3)
    for name in set(TRUTH) - set(implied):
        assert re.search(rf"^{name} .*unchanged", text, re.M) and TRUTH[name].cpi == ROUGH[name].cpi
    # Distance: within 0.5 mm of the true one (and away from the configured 260 mm).
    text = _output(ran, "distance")
    d = float(re.search(r"distance left - right: ([\d.]+) \+-", text).group(1)) / 1000
    assert d == pytest.approx(GEN.true_distance(), abs=5e-4)
    assert abs(d - 0.26) > 1e-3
    # Mounts, exact fit: every position within 0.5 mm, every scale within 0.3 % of the truth.
    text = _output(ran, "mounts")
    fits = re.findall(r"^  (\w+): x ([-\d.]+) mm, y ([-\d.]+) mm, yaw [-\d.]+ deg, scale "
                      r"([\d.]+)", text, re.M)  # fmt: skip
    assert {f[0] for f in fits} == set(TRUTH)
    for name, x, y, scale in fits:
        t = TRUTH[name]
        assert math.hypot(float(x) / 1000 - t.x, float(y) / 1000 - t.y) < 5e-4, name
        assert float(scale) == pytest.approx(t.cpi / ROUGH[name].cpi, rel=3e-3), name
    # UMBmark: the rough config's systematic error is large; the true values' is noise.
    before = _output(ran, "umbmark", "cal-umbmark.csv")
    after = _output(ran, "umbmark", "cal-umbmark-after.csv")
    e = [float(re.search(r"E_max,syst = ([\d.]+) mm", t).group(1)) for t in (before, after)]
    assert e[0] > 100 and e[1] < 10, e


def test_the_write_example_wrote_the_calibration(ran):
    # After `calibrate mounts --write`, the calibration file holds the fitted mounts.
    text = _output(ran, "check-config")
    assert re.search(r"front: cpi 81[12]\.\d+/", text), text
    assert "(applied)" in text


def test_line_matching_allows_rounding_spaces_and_elisions_only():
    assert _line_matches("a 1.25 mm  (b)", "a 1.26 mm (b)") is None
    assert _line_matches("a 1.25 mm", "a 1.27 mm") == "1.27 where the docs show 1.25"
    assert _line_matches("x 8.1e-05", "x 8.2e-05") is None
    assert _line_matches("written to .../f.yaml", "written to /tmp/x/f.yaml") is None
    assert _line_matches("written to .../f.yaml", "written to /tmp/x/g.yaml") is not None
    assert _line_matches("cpi y = 800", "cpi x = 800") == "the words differ"


def test_running_from_the_data_directory_itself_is_not_needed():
    # The docs tell users to copy the samples: an installed package's directory may not be
    # writable, and --write would write there.  Nothing in the docs cds into it.
    assert not any(c.startswith("cd ") for c, _ in EXAMPLES)
    assert os.access(DATA, os.R_OK)
