"""tests/data/external is the byte-exact copy SOURCES.md describes (git blob ids match)."""

from __future__ import annotations

import hashlib
import re

from conftest import external_dir


def test_every_recording_matches_its_published_blob():
    """Each file listed in SOURCES.md hashes to the blob id of the public repository it
    was copied from, so the tests run on the recordings as published."""
    d = external_dir()
    text = (d / "SOURCES.md").read_text()
    rows = re.findall(r"^\| (\S+\.(?:events|desc))\S* .*\| ([0-9a-f]{40}) \| (\d+) \|$", text, re.M)
    assert len(rows) >= 7
    for name, blob, size in rows:
        data = (d / name).read_bytes()
        assert len(data) == int(size), name
        assert hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest() == blob, name
