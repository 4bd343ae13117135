"""The import rules of docs/design.md ("Rooms and import rules"), read from the source.

Data flows one way: the model and the accelerator at the bottom, pure control math above
them, the link, the simulated vehicle and the flight log beside it, the controller on top
of those, the harness that puts a vehicle and a controller together, and the command line
over everything. A rule broken here is an arrow that runs back up.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "tfl_mav"

# Modules at the package's top level that the lower rooms share (scenario files and the
# expressions in them); the rest of the top level is the public face (api, gym, ...).
SHARED_TOP = {"tfl_mav.scenario", "tfl_mav.expr", "tfl_mav"}

# room → rooms it may import besides itself ("control" is the control package's top level;
# "control.tfl" etc. its rooms).
ALLOWED: dict[str, set[str]] = {
    "model": set(),
    "accel": set(),
    "link": set(),
    "control": {"model", "accel", "control", "control.tfl", "control.path", "shared"},
    "control.path": {"model", "accel", "control", "shared"},
    "control.tfl": {"model", "accel", "control", "control.path", "shared"},
    "control.safe": {"model", "accel", "control", "control.path", "control.tfl", "shared"},
    "control.detect": {"model", "accel", "control", "shared"},
    # the spin law designs its gains with the safe law's numpy LQR (control.safe.lqr)
    "control.spin": {"model", "accel", "control", "control.safe", "shared"},
    "sim": {"model", "accel", "link", "shared"},
    # a finished flight's reader rebuilds the scenario's path (flightlog.from_mcap)
    "flightlog": {"model", "accel", "link", "control.path", "shared", "build"},
    "controller": {"model", "accel", "link", "flightlog", "control", "control.path",
                   "control.tfl", "control.safe", "control.detect", "control.spin", "shared",
                   "build"},
    # campaigns fly a user's controller through the public API (tfl_mav.api, comparison)
    "harness": {"model", "accel", "link", "flightlog", "sim", "controller", "control",
                "control.path", "control.tfl", "control.safe", "control.detect",
                "control.spin", "shared", "build", "top", "baselines"},
}


def _room(module: str) -> str:
    parts = module.split(".")
    if module in SHARED_TOP:
        return "shared"
    if module == "tfl_mav.build":
        return "build"
    if len(parts) == 2:
        return "top"
    if parts[1] == "control":
        return "control" if len(parts) == 3 and not (PACKAGE / "control" / parts[2]).is_dir() \
            else f"control.{parts[2]}"
    return parts[1]


def _module_of(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> list[str]:
    """Every tfl_mav module ``path`` imports, at top level or inside a function."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "tfl_mav":
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                is_module = (PACKAGE.parent / (sub.replace(".", "/") + ".py")).exists() or \
                    (PACKAGE.parent / sub.replace(".", "/")).is_dir()
                out.append(sub if is_module else node.module)
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names if a.name.split(".")[0] == "tfl_mav"]
    return out


SOURCES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_run_one_way(path: Path) -> None:
    room = _room(_module_of(path))
    if room == "cli":
        return                                   # the command line may use every room
    bad = []
    for target in _imports(path):
        other = _room(target)
        if other == "cli":
            bad.append(f"{target} (nothing imports the command line)")
        elif room in ALLOWED and other != room and other not in ALLOWED[room]:
            bad.append(target)
    assert not bad, f"{path.relative_to(PACKAGE)} ({room}) imports {', '.join(bad)}"


def test_the_rules_cover_every_room() -> None:
    rooms = {_room(_module_of(p)) for p in SOURCES}
    assert rooms - set(ALLOWED) <= {"top", "shared", "build", "cli", "baselines"}


def test_a_broken_rule_is_seen(tmp_path: Path) -> None:
    """The reader finds an upward import inside a function (so the rules can fail)."""
    src = tmp_path / "x.py"
    src.write_text("def f():\n    from tfl_mav.controller.daemon import Daemon\n")
    assert "tfl_mav.controller.daemon" in _imports(src)
    assert _room("tfl_mav.controller.daemon") not in ALLOWED["control"]
