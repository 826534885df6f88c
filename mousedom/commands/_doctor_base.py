"""What every check of ``mousedom doctor`` shares: the verdicts, a line of the report
(``Check``), the lines of one check (``Lines``), and where this mousedom is."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

OK, WARN, FAIL = "OK", "WARN", "FAIL"
PACKAGE = Path(__file__).resolve().parents[1]  # this mousedom, wherever it was imported


@dataclass
class Check:
    """One line of the report: which check, its verdict, what was found, what to do."""

    check: str  # config, devices, calibration, daemon, ros2, metrics, core
    status: str  # OK, WARN or FAIL
    message: str
    hint: str | None = None
    data: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        if not d["data"]:
            del d["data"]
        return d


class Lines(list):
    """The lines of one check, added by verdict."""

    def __init__(self, check: str) -> None:
        super().__init__()
        self.check = check

    def ok(self, message: str, **data: Any) -> None:
        self.append(Check(self.check, OK, message, None, data))

    def warn(self, message: str, hint: str | None, **data: Any) -> None:
        self.append(Check(self.check, WARN, message, hint, data))

    def fail(self, message: str, hint: str | None, **data: Any) -> None:
        self.append(Check(self.check, FAIL, message, hint, data))
