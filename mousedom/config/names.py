"""What a mouse's name becomes where it names something else.

A config may call a mouse anything YAML can write ("front-left", "2nd", "Mouse A").  The
replay CSV suffixes its per-mouse columns with the name, and ROS 2 (the live output and
the MCAP recording) names the mouse's counts topic and its TF frame after it; neither
takes every character.  Two mice whose names become the same there would share a column
or a topic, so the config refuses them (``clash``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

_NOT_TOKEN = re.compile(r"[^A-Za-z0-9]+")


def column_suffix(name: str) -> str:
    """The name as a CSV column's suffix: a comma or a quote would break the CSV."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def ros_token(name: str) -> str:
    """The name as one token of a ROS 2 name (design.ros2.org, "Topic and Service names"):
    letters, digits and single underscores, not starting with a digit nor starting or
    ending with an underscore.  Each run of other characters becomes one underscore;
    a name that would start with a digit, or has no letter or digit at all, is prefixed
    "m_" ("2nd" -> "m_2nd", "front-left" -> "front_left")."""
    token = _NOT_TOKEN.sub("_", name).strip("_")
    if not token or token[0].isdigit():
        token = "m_" + token if token else "m"
    return token


def clash(names: Sequence[str]) -> str | None:
    """A sentence naming two mice whose names become the same column suffix or ROS 2
    token, or None."""
    for rule, what in ((column_suffix, "the replay CSV's column suffix"),
                       (ros_token, "the ROS 2 name")):  # fmt: skip
        seen: dict[str, str] = {}
        for name in names:
            made = rule(name)
            if made in seen:
                return f"mice {seen[made]!r} and {name!r} both become {what} {made!r}: rename one"
            seen[made] = name
    return None
