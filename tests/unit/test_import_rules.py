"""The import rules of docs/design.md ("Rooms and import rules"), read from the source.

Data flows one way: the model and the accelerator at the bottom, pure control math above
them, the link and the flight log beside it, the controller on top of those. The vehicle
(``sitl/``, imported as ``tfl_mav.sitl``) stands beside the controller and never sees it;
the controller side never imports the vehicle. The public face (``api``, ``offline``,
``gym``, ``comparison``) flies both together in one process, and the tools (``tools/``,
imported as ``tfl_mav.tools``: the harness and, over everything, the command line) put
them together across processes. A rule broken here is an arrow that runs back up.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# import-name prefix → directory, as pyproject.toml's package-dir maps them
ROOTS = {"tfl_mav": REPO / "tfl_mav", "tfl_mav.sitl": REPO / "sitl",
         "tfl_mav.tools": REPO / "tools"}

# Modules at the package's top level that every room shares (scenario files and the
# expressions in them, the flight logs' Foxglove layouts: data packages, the package itself).
SHARED_TOP = {"tfl_mav.scenario", "tfl_mav.expr", "tfl_mav", "tfl_mav.scenarios",
              "tfl_mav.layouts"}
# The public face: fly flight software on the simulated vehicle in one process.
FACE = {"tfl_mav.api", "tfl_mav.offline", "tfl_mav.gym", "tfl_mav.comparison"}

CONTROL_ROOMS = {"control", "control.path", "control.tfl", "control.safe", "control.detect",
                 "control.spin"}
# The controller side: everything under tfl_mav/ except the public face.
CONTROLLER_SIDE = {"model", "accel", "link", "flightlog", "controller", "baselines", "shared",
                   "from_scenario", *CONTROL_ROOMS}

# room → rooms it may import besides itself ("control" is the control package's top level;
# "control.tfl" etc. its rooms).
ALLOWED: dict[str, set[str]] = {
    "shared": {"control.detect", "control"},   # a scenario's [detector] is the detector's config
    "model": set(),
    "accel": set(),
    "link": set(),
    "control": {"model", "accel", "control.tfl", "control.path", "shared"},
    "control.path": {"model", "accel", "control", "shared"},
    "control.tfl": {"model", "accel", "control", "control.path", "shared"},
    "control.safe": {"model", "accel", "control", "control.path", "control.tfl", "shared"},
    "control.detect": {"model", "accel", "control", "shared"},
    # the spin law designs its gains with the safe law's numpy LQR (control.safe.lqr)
    "control.spin": {"model", "accel", "control", "control.safe", "shared"},
    # a scenario → the controller's model, law, path, detector
    "from_scenario": {"model", "control", *CONTROL_ROOMS, "shared"},
    # a finished flight's reader rebuilds the scenario's path (flightlog.from_mcap)
    "flightlog": {"model", "accel", "link", "control.path", "shared", "from_scenario"},
    "controller": {"model", "accel", "link", "flightlog", "control", *CONTROL_ROOMS, "shared",
                   "from_scenario"},
    "baselines": {"model", "control", *CONTROL_ROOMS, "shared", "from_scenario"},
    # the vehicle: never the controller, its laws or its log
    "sitl": {"model", "accel", "link", "shared"},
    "face": CONTROLLER_SIDE | {"sitl"},
    # campaigns fly a user's controller through the public face (tfl_mav.api, comparison)
    "tools": set(),                               # the package's docstring
    "tools.harness": CONTROLLER_SIDE | {"sitl", "face"},
    "tools.cli": CONTROLLER_SIDE | {"sitl", "face", "tools.harness"},
}


def _room(module: str) -> str:
    parts = module.split(".")
    if module in SHARED_TOP:
        return "shared"
    if module in FACE:
        return "face"
    if module == "tfl_mav.from_scenario":
        return "from_scenario"
    if parts[1] == "tools":
        return "tools" if len(parts) == 2 else f"tools.{parts[2]}"
    if parts[1] == "control":
        if len(parts) == 2 or (len(parts) == 3 and
                               not (REPO / "tfl_mav" / "control" / parts[2]).is_dir()):
            return "control"
        return f"control.{parts[2]}"
    if len(parts) == 2 and not (REPO / "tfl_mav" / parts[1]).is_dir() and parts[1] != "sitl":
        return "top"                             # a top-level module no rule names
    return parts[1]


def _file_of(module: str) -> Path | None:
    """The file or package directory ``module`` names, by the package-dir mapping."""
    for prefix in sorted(ROOTS, key=len, reverse=True):
        if module == prefix or module.startswith(prefix + "."):
            rest = module[len(prefix):].lstrip(".")
            base = ROOTS[prefix].joinpath(*rest.split(".")) if rest else ROOTS[prefix]
            if base.with_suffix(".py").exists():
                return base.with_suffix(".py")
            return base if base.is_dir() else None
    return None


def _module_of(path: Path) -> str:
    for prefix in sorted(ROOTS, key=len, reverse=True):
        root = ROOTS[prefix]
        if path.is_relative_to(root):
            parts = [*prefix.split("."), *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            return ".".join(parts)
    raise ValueError(f"{path} is in none of {sorted(ROOTS)}")


def _imports(path: Path) -> list[str]:
    """Every tfl_mav module ``path`` imports, at top level or inside a function."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "tfl_mav":
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                out.append(sub if _file_of(sub) is not None else node.module)
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names if a.name.split(".")[0] == "tfl_mav"]
    return out


SOURCES = sorted(p for root in ROOTS.values() for p in root.rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(REPO)))
def test_imports_run_one_way(path: Path) -> None:
    room = _room(_module_of(path))
    bad = []
    for target in _imports(path):
        other = _room(target)
        if other == "tools.cli" and room != "tools.cli":
            bad.append(f"{target} (nothing imports the command line)")
        elif other != room and other not in ALLOWED.get(room, set()):
            bad.append(target)
    assert not bad, f"{path.relative_to(REPO)} ({room}) imports {', '.join(bad)}"


def test_the_rules_cover_every_room() -> None:
    """Every module has a rule: the top level of tfl_mav/ included, no room left unchecked."""
    rooms = {_room(_module_of(p)) for p in SOURCES}
    assert rooms <= set(ALLOWED), sorted(rooms - set(ALLOWED))


def test_the_controller_side_never_imports_the_vehicle() -> None:
    for room in CONTROLLER_SIDE:
        assert not ALLOWED[room] & {"sitl", "face", "tools", "tools.harness", "tools.cli"}, room
    assert not ALLOWED["sitl"] & (CONTROLLER_SIDE - {"model", "accel", "link", "shared"})


def test_the_directories_map_to_import_names() -> None:
    assert _module_of(REPO / "sitl" / "vehicle.py") == "tfl_mav.sitl.vehicle"
    assert _module_of(REPO / "tools" / "cli" / "__init__.py") == "tfl_mav.tools.cli"
    assert _file_of("tfl_mav.sitl.simulator") == REPO / "sitl" / "simulator.py"
    assert _room("tfl_mav.offline") == "face" and _room("tfl_mav.sitl.clock") == "sitl"


def test_a_broken_rule_is_seen(tmp_path: Path) -> None:
    """The reader finds an upward import inside a function (so the rules can fail)."""
    src = tmp_path / "x.py"
    src.write_text("def f():\n    from tfl_mav.controller.daemon import Daemon\n"
                   "    from tfl_mav.sitl.simulator import Simulator\n")
    found = _imports(src)
    assert "tfl_mav.controller.daemon" in found and "tfl_mav.sitl.simulator" in found
    assert _room("tfl_mav.controller.daemon") not in ALLOWED["control"]
    assert _room("tfl_mav.sitl.simulator") not in ALLOWED["controller"]
