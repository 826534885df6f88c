"""The layout's one rule, held by reading the imports: arrows only point down.

    commands, cli                          the CLI
    service, calibrate, client, plot, demo what the CLI runs
    capture                                file formats, the replay engine, replay sources
    sources                                devices -> reports (evdev, ADNS-3080)
    fusion                                 the pure engine: no I/O, time as data
    config, yamldoc, errors, safeyaml,     what every room uses
    safewrite, plainnumber, hangup,
    invocation, core

A module may import from its own room and from the rooms below it, never from above
(docs/architecture.md).  One exception is written down: ``config`` checks a rig's rank at
load with ``fusion.geometry``, and takes the model and integrator names from
``fusion.choices``: leaves that import nothing of ours.  Every import counts,
including those inside functions (a late import is still an arrow).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / "mousedom"

LAYERS = [
    {"commands", "cli", "__main__"},
    {"service", "calibrate", "client", "plot", "demo"},
    {"capture"},
    {"sources"},
    {"fusion", "observability"},
    {
        "config",
        "yamldoc",
        "errors",
        "safeyaml",
        "safewrite",
        "saferead",
        "plausible",
        "plainnumber",
        "hangup",
        "angles",
        "invocation",
        "allocator",
        "core",
        "_core",
        "__init__",
    },
]
# config checks a rig's rank with fusion.geometry and takes the names of the models and
# integrators from fusion.choices: two leaves that import nothing of ours.
ALLOWED_UP = {("config", "mousedom.fusion.geometry"), ("config", "mousedom.fusion.choices")}


def room_of(module: str) -> str:
    """'mousedom.fusion.tracker' -> 'fusion'; 'mousedom' -> '__init__'."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def level(room: str) -> int:
    for i, rooms in enumerate(LAYERS):
        if room in rooms:
            return i
    raise KeyError(f"room {room!r} is in no layer: add it to LAYERS (and the docs)")


def imports_of(source: str, module: str) -> list[tuple[int, str]]:
    """(line, imported mousedom module) of every import in a module's source."""
    out = []
    package = module if module.endswith("__init__") else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("mousedom")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if not name.startswith("mousedom"):
                continue
            if name == "mousedom":  # from mousedom import fusion  -> the submodules
                out += [
                    (node.lineno, "mousedom" if a.name.startswith("__") else f"mousedom.{a.name}")
                    for a in node.names
                ]
            else:
                out.append((node.lineno, name))
    return out


def violations(modules: dict[str, str]) -> list[str]:
    """Every import that points up: ``modules`` maps dotted module names to their source."""
    bad = []
    for module, source in sorted(modules.items()):
        here = room_of(module)
        for line, target in imports_of(source, module):
            there = room_of(target)
            if (here, target) in ALLOWED_UP or there == here:
                continue
            if level(there) < level(here):
                bad.append(f"{module}:{line}: {here} imports {target} ({there} is above it)")
    return bad


def package_modules() -> dict[str, str]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(REPO).with_suffix("")
        out[".".join(rel.parts)] = path.read_text()
    return out


def test_every_arrow_points_down():
    assert violations(package_modules()) == []


# The daemon's parts, from the composition root down (docs/architecture.md, "The daemon's
# parts"): a part imports only parts after it; every other service module is a leaf that
# imports no part, so none reaches the daemon or a part above it.
SERVICE_PARTS = ["daemon", "reload", "control", "publish", "slots"]


def service_violations(modules: dict[str, str]) -> list[str]:
    bad = []
    for module, source in sorted(modules.items()):
        if not module.startswith("mousedom.service."):
            continue
        here = module.split(".")[2]
        rank = SERVICE_PARTS.index(here) if here in SERVICE_PARTS else len(SERVICE_PARTS)
        for line, target in imports_of(source, module):
            parts = target.split(".")
            if parts[:2] != ["mousedom", "service"] or len(parts) < 3:
                continue
            there = parts[2]
            if there in SERVICE_PARTS and SERVICE_PARTS.index(there) <= rank and there != here:
                bad.append(f"{module}:{line}: imports the part {target}, above or beside it")
    return bad


def test_the_daemons_parts_import_only_down():
    assert service_violations(package_modules()) == []


def test_the_service_rule_sees_an_arrow_up():
    modules = {
        "mousedom.service.slots": "from mousedom.service.publish import Publisher\n",
        "mousedom.service.server": "from mousedom.service.daemon import Daemon\n",
        "mousedom.service.reload": "from mousedom.service.slots import Sensors\n",
    }
    assert service_violations(modules) == [
        "mousedom.service.server:1: imports the part mousedom.service.daemon, above or beside it",
        "mousedom.service.slots:1: imports the part mousedom.service.publish, above or beside it",
    ]


def test_every_room_is_in_a_layer():
    for module in package_modules():
        level(room_of(module))


def test_the_fusion_engine_does_no_io():
    """fusion is pure: no file, socket, clock or process modules."""
    io = {"os", "socket", "select", "selectors", "subprocess", "time", "serial", "evdev",
          "pathlib", "shutil", "tempfile", "signal", "logging"}  # fmt: skip
    for module, source in package_modules().items():
        if room_of(module) != "fusion":
            continue
        for node in ast.walk(ast.parse(source)):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [(node.module or "").split(".")[0]]
            assert not set(names) & io, f"{module}:{node.lineno} imports {names}"


@pytest.mark.parametrize(
    "module, source, words",
    [
        (
            "mousedom.fusion.tracker",
            "from mousedom.service.server import Server\n",
            "fusion imports",
        ),
        (
            "mousedom.sources.evdev",
            "def f():\n    import mousedom.service.daemon\n",
            "sources imports",
        ),
        (
            "mousedom.sources.evdev",
            "from mousedom.capture import open_capture\n",
            "capture is above",
        ),
        ("mousedom.capture.base", "from ..service import protocol\n", "service is above"),
        ("mousedom.fusion.sim", "from mousedom import commands\n", "commands is above"),
    ],
)
def test_the_rule_can_fail(module, source, words):
    """The checker itself: an upward import, however written, is caught."""
    bad = violations({module: source})
    assert len(bad) == 1 and words in bad[0], bad


def test_a_room_may_use_its_own_and_lower_rooms():
    ok = {
        "mousedom.service.daemon": "from mousedom.fusion import tracker\nfrom . import server\n",
        "mousedom.capture.replay": "from mousedom.sources.adns import replay_decoder\n",
        "mousedom.config": "def f():\n    from mousedom.fusion.geometry import rank_problem\n",
    }
    assert violations(ok) == []
