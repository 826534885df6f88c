"""``mousedom list``'s suggested rule for a device reads back, in a config, as a rule that
matches that device: whatever its name, phys, uniq or node (a review's generated devices:
a uniq 0123 was refused as an octal-looking number, 1e5 became 100000.0, yes True; an
emoji's name came back as a surrogate pair YAML refuses)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.commands.list import suggested_rule
from mousedom.config import ConfigError, parse_config
from mousedom.sources.discovery import DeviceInfo, matches

_TEXT = st.text(st.characters(blacklist_categories=("Cs", "Cc")), min_size=1, max_size=30)


def _config(rule: str) -> str:
    return (
        f"model: diff-drive\nmice:\n  m: {{cpi: 800, mount: {{x: 0.1, y: 0.0, yaw: 0}}, {rule}}}\n"
    )


@settings(max_examples=300, deadline=None)
@given(
    name=_TEXT, phys=_TEXT | st.just(""), uniq=_TEXT | st.sampled_from(["0123", "1e5", "yes", "~"]),
    by_path=st.booleans(), vendor=st.integers(0, 0xFFFF), product=st.integers(0, 0xFFFF),
)  # fmt: skip
def test_the_suggested_rule_reads_back_as_one_that_matches_the_device(
    name, phys, uniq, by_path, vendor, product
):
    dev = DeviceInfo(
        node="/dev/input/event7", name=name, phys=phys, uniq=uniq, vendor=vendor,
        product=product, rel_x=True, rel_y=True,
        by_path=("/dev/input/by-path/pci-0000:00:14.0-usb-0:2:1.0-event-mouse",) if by_path
        else (),
    )  # fmt: skip
    rule = suggested_rule(dev)
    cfg = parse_config(_config(rule), "rig.yaml", need_sources=True)
    assert matches(cfg.mice[0].evdev, dev), rule


def test_a_product_alone_is_a_rule_and_ids_beyond_16_bits_are_refused():
    """docs/evdev.md: vendor/product; a rule of the product alone was refused as naming
    nothing, and a vendor of -1 or 0x1046d, which no device has, was taken."""
    cfg = parse_config(_config("evdev: {product: 0xc077}"), "rig.yaml")
    assert cfg.mice[0].evdev.product == 0xC077
    for bad in ("-1", "0x1046d"):
        with pytest.raises(ConfigError, match=r"mice.m.evdev.vendor: must be a USB id of 16 bits"):
            parse_config(_config(f"evdev: {{vendor: {bad}}}"), "rig.yaml")
