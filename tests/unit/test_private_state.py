"""No object reads another's private state: an underscore attribute is read through ``self``
or ``cls`` only, in every module of the three directories (tfl_mav/, sitl/, tools/) and in
every test (which, besides, imports no private name of the project and names no private
attribute in a string: ``monkeypatch.setattr(native, "_loaded", ...)`` is a write all the
same).

What another object offers is its public, documented attributes and methods; ``x._name``
with ``x`` anything else is a reach into state its owner may change without telling anyone.
Not counted: dunders (``__class__``), the NamedTuple API (``_replace``, ``_asdict``,
``_fields``, ``_make``: public despite the underscore) and attributes of a module imported
from outside the project (``argparse._SubParsersAction``: not ours to give an accessor).
Nothing is allowlisted. The benchmarks (bench/) time private pieces on purpose, white box,
and are not product code: they are not read here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SOURCES = sorted(p for d in ("tfl_mav", "sitl", "tools") for p in (REPO / d).rglob("*.py"))
NAMEDTUPLE_API = {"_replace", "_asdict", "_fields", "_make", "_field_defaults"}


def _foreign_modules(tree: ast.Module) -> set[str]:
    """Names bound to modules imported from outside tfl_mav (``import argparse``)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] != "tfl_mav":
                    out.add(a.asname or a.name.split(".")[0])
    return out


def private_reads(source: str) -> list[str]:
    """``line: expression`` of every underscore attribute read through another object."""
    tree = ast.parse(source)
    foreign = _foreign_modules(tree)
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        name = node.attr
        if not name.startswith("_") or name.startswith("__") or name in NAMEDTUPLE_API:
            continue
        owner = node.value
        if isinstance(owner, ast.Name) and owner.id in ({"self", "cls"} | foreign):
            continue
        out.append(f"{node.lineno}: {ast.unparse(node)}")
    return out


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(REPO)))
def test_no_module_reads_another_objects_private_state(path: Path) -> None:
    found = private_reads(path.read_text())
    assert not found, f"{path.relative_to(REPO)} reads private state: {'; '.join(found)}"


def private_imports(source: str) -> list[str]:
    """``line: module.name`` of every underscore name imported from the project."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "tfl_mav":
            out += [f"{node.lineno}: {node.module}.{a.name}" for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")]
    return out


def private_by_name(source: str) -> list[str]:
    """``line: call`` of every ``getattr``/``setattr``/``hasattr``/``delattr`` (and
    ``monkeypatch.setattr``/``delattr``) of an underscore name given as a string."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.Call) and len(node.args) >= 2):
            continue
        fn = node.func
        name = fn.id if isinstance(fn, ast.Name) else fn.attr if isinstance(
            fn, ast.Attribute) else ""
        attr = node.args[1]
        if name in ("getattr", "setattr", "hasattr", "delattr") \
                and isinstance(attr, ast.Constant) and isinstance(attr.value, str) \
                and attr.value.startswith("_") and not attr.value.startswith("__") \
                and attr.value not in NAMEDTUPLE_API:
            out.append(f"{node.lineno}: {ast.unparse(node)}")
    return out


# The tests hold the same rule, and import no private name of the project either: a test
# asks an object what a user could ask, so it fails when the behaviour breaks, not when a
# name inside it is changed. (The suite's own helpers, ``tests.…``, are not the project's.)
TESTS = sorted((REPO / "tests").rglob("*.py"))


@pytest.mark.parametrize("path", TESTS, ids=lambda p: str(p.relative_to(REPO)))
def test_no_test_reaches_into_the_projects_private_state(path: Path) -> None:
    source = path.read_text()
    found = private_reads(source) + private_imports(source) + private_by_name(source)
    assert not found, f"{path.relative_to(REPO)} reaches into private state: {'; '.join(found)}"


def test_a_private_import_is_seen() -> None:
    src = ("from tfl_mav.flightlog.metrics import _median, median\n"
           "from tests.contract.test_accel import _bits\n"
           "from argparse import _SubParsersAction\n")
    assert [f.split(": ")[1] for f in private_imports(src)] == ["tfl_mav.flightlog.metrics._median"]


def test_a_private_name_given_as_a_string_is_seen() -> None:
    src = ("monkeypatch.setattr(native, '_loaded', {})\n"
           "ok = hasattr(sim, '_rk4_air') or getattr(t, '_fields', None) or getattr(t, 'x')\n"
           "monkeypatch.setattr(native, 'mode', lambda: 'off')\n")
    assert [f.split(": ")[1] for f in private_by_name(src)] == [
        "monkeypatch.setattr(native, '_loaded', {})", "hasattr(sim, '_rk4_air')"]


def test_a_reach_into_another_object_is_seen() -> None:
    """The reader finds each form of the reach (so the rule can fail), and lets the rest be."""
    src = ("import argparse\n"
           "from tfl_mav.sitl import simulator\n"
           "def f(sim, tracker, a):\n"
           "    t = sim._time_usec\n"                 # another object's field
           "    g = tracker.path._grad_s(t)\n"        # through a public attribute
           "    c = simulator._round(1.0)\n"          # a project module's private name
           "    s = argparse._SubParsersAction\n"     # outside the project: not ours
           "    return a._replace(x=1), a.__class__, type(a)._fields\n")
    found = private_reads(src)
    assert [f.split(": ")[1] for f in found] == ["sim._time_usec", "tracker.path._grad_s",
                                                 "simulator._round"]


# The objects the flight computer holds and steers: its laws and filters.
FLIGHT_COMPUTER = REPO / "tfl_mav" / "controller" / "flight_computer.py"
FLIGHT_COMPUTER_HOLDS = {"controller", "recovery", "detector", "state_filter", "yaw_model"}


def _held(e: ast.expr, holds: set[str], held_names: set[str]) -> bool:
    """``e`` is a held object: ``self.<name>`` (``name`` in ``holds``) or a local bound to one."""
    return (isinstance(e, ast.Attribute) and isinstance(e.value, ast.Name)
            and e.value.id == "self" and e.attr in holds) or (
        isinstance(e, ast.Name) and e.id in held_names)


def _part(e: ast.expr, holds: set[str], held_names: set[str], part_names: set[str]) -> bool:
    """``e`` is a part of a held object (an attribute of it), or a local bound to one."""
    return (isinstance(e, ast.Attribute) and _held(e.value, holds, held_names)) or (
        isinstance(e, ast.Name) and e.id in part_names)


def reaches_through(source: str, holds: set[str]) -> list[str]:
    """``line: expression`` of every write into an object held as ``self.<name>`` (``name``
    in ``holds``) and every use of one of its parts — an attribute of an attribute of it
    (``self.recovery.projector.lam``, ``self.controller.lag_inverter.reset``) — also through
    a local name bound to it or to its part (``rec = self.recovery``; ``proj =
    rec.projector``). A held object is asked through its own methods and properties; its
    parts are its own business."""
    tree = ast.parse(source)
    out = []
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        held_names: set[str] = set()
        part_names: set[str] = set()
        for node in ast.walk(fn):
            if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                    and isinstance(node.targets[0], ast.Name):
                if _held(node.value, holds, held_names):
                    held_names.add(node.targets[0].id)
                elif _part(node.value, holds, held_names, part_names):
                    part_names.add(node.targets[0].id)
        for node in ast.walk(fn):
            if not isinstance(node, ast.Attribute) or node.attr in NAMEDTUPLE_API:
                continue
            if (isinstance(node.ctx, ast.Store) and _held(node.value, holds, held_names)) \
                    or _part(node.value, holds, held_names, part_names):
                out.append(f"{node.lineno}: {ast.unparse(node)}")
    return sorted(set(out), key=lambda s: int(s.split(":")[0]))


def test_the_flight_computer_steers_its_laws_through_their_methods() -> None:
    found = reaches_through(FLIGHT_COMPUTER.read_text(), FLIGHT_COMPUTER_HOLDS)
    assert not found, f"the flight computer reaches into its laws: {'; '.join(found)}"


def test_a_reach_through_a_held_object_is_seen() -> None:
    src = ("class FC:\n"
           "    def tick(self, y):\n"
           "        self.recovery.projector.lam = None\n"      # a part's field, written
           "        rec = self.recovery\n"
           "        rec.hold_m = y\n"                           # the law's field, written
           "        lag = self.controller.lag_inverter\n"
           "        lag.reset()\n"                              # a part, used
           "        k = self.controller.model.k_f\n"            # a part, read
           "        out = rec.update(y)\n"                      # asked: fine
           "        return out.thrust_n, rec.holding, self.controller.has_motor_lag, k\n")
    found = reaches_through(src, {"controller", "recovery"})
    assert [f.split(": ")[1] for f in found] == [
        "self.recovery.projector.lam", "rec.hold_m", "lag.reset", "self.controller.model.k_f"]
