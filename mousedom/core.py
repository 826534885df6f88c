"""Which core runs: the compiled one (``mousedom._core``, csrc/*.c) where it was built,
else the Python, which is its specification (issue 28; docs/install.md).

``MOUSEDOM_CORE=python`` forces the Python even where the compiled core is built (to
compare, or to rule it out); ``MOUSEDOM_CORE=c`` refuses to start without it (CI, and a
robot whose image must have it).  Read once, at import: a running process does not
switch cores.
"""

from __future__ import annotations

import os
from types import ModuleType

from mousedom.errors import UserError


def _load() -> tuple[ModuleType | None, str]:
    wanted = os.environ.get("MOUSEDOM_CORE", "").strip().lower()
    if wanted not in ("", "c", "python"):
        raise UserError(f"MOUSEDOM_CORE={wanted!r}: expected 'c' or 'python' (or unset)")
    if wanted == "python":
        return None, "python (MOUSEDOM_CORE=python)"
    try:
        from mousedom import _core  # type: ignore[attr-defined]
    except ImportError as e:
        if wanted == "c":
            raise UserError(
                f"MOUSEDOM_CORE=c, but the compiled core does not load ({e}): build it with "
                "gcc and the Python headers (docs/install.md)"
            ) from e
        return None, "python (no compiled core built)"
    return _core, "c"


native, NAME = _load()
