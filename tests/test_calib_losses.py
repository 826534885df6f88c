"""Calibration from captures that lost counts: frames the kernel dropped (SYN_DROPPED) are
an error, as lost serial packets are, and what the capture readers warn of is said."""

from __future__ import annotations

from test_calib_cli import calib, cpi_session, ok  # noqa: F401  (cpi_session: a fixture)


def _with_syn_dropped(path, every: int) -> None:
    """A SYN_DROPPED in every ``every``-th frame (the kernel's buffer overflowed): the
    reader discards that frame's events, as the kernel's protocol says."""
    out, frame = [], 0
    for line in path.read_text().splitlines():
        fields = line.split()
        if fields[:1] == ["E:"] and fields[2:4] == ["0000", "0000"]:  # a SYN_REPORT
            if frame % every == 0:
                out.append(f"E: {fields[1]} 0000 0003 0000")
            frame += 1
        out.append(line)
    path.write_text("\n".join(out) + "\n")


def test_a_capture_with_frames_the_kernel_dropped_is_refused(cpi_session):  # noqa: F811
    """The sample drive with a SYN_DROPPED in every 5th frame gave a CPI 20 % off, exit 0,
    and ``--write`` stored it; replay of the same files said 210 frames were dropped."""
    tmp, cfg, files = cpi_session
    _with_syn_dropped(files["right"], 5)
    caps = [a for n, f in files.items() for a in ("--capture", f"{n}={f}")]
    p = calib("cpi", cfg, *caps, "--distance", "0.2", "--write")
    assert p.returncode != 0, p.stdout
    assert "Traceback" not in p.stderr
    assert "frame(s) dropped by the kernel (SYN_DROPPED" in p.stderr, p.stderr
    assert "mouse right" in p.stderr and "right.events" in p.stderr, p.stderr
    assert not (tmp / "rig.calib.yaml").exists()


def test_what_the_capture_readers_warn_of_is_said(cpi_session):  # noqa: F811
    """A recording cut off mid-line: replay says so, and calibration said nothing."""
    tmp, cfg, files = cpi_session
    text = files["left"].read_text()
    files["left"].write_text(text[: len(text) - 7])
    caps = [a for n, f in files.items() for a in ("--capture", f"{n}={f}")]
    p = ok(calib("cpi", cfg, *caps, "--distance", "0.2"))
    assert "left.events" in p.stderr and "last line cut off" in p.stderr, p.stderr
