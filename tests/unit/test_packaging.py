"""pyproject.toml installs every package of the three directories under the one import name.

The packages are listed by hand (setuptools cannot find packages through a package-dir
mapping), so a new package directory missing from the list would be absent from a regular
``pip install .`` while an editable install still finds it: this test is where that shows.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONFIG = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]


def _packages_on_disk() -> set[str]:
    roots = {"tfl_mav": REPO / "tfl_mav", **{name: REPO / where for name, where in
                                              CONFIG["package-dir"].items()}}
    found = set()
    for name, root in roots.items():
        for init in root.rglob("__init__.py"):
            rel = init.parent.relative_to(root).parts
            found.add(".".join((name, *rel)))
    return found


def test_every_package_directory_is_installed() -> None:
    assert set(CONFIG["packages"]) == _packages_on_disk()


def test_no_bare_top_level_name_but_tfl_mav() -> None:
    """sitl/ and tools/ are names PyPI already has: they install under tfl_mav only."""
    assert {p.split(".")[0] for p in CONFIG["packages"]} == {"tfl_mav"}
    assert CONFIG["package-dir"] == {"tfl_mav.sitl": "sitl", "tfl_mav.tools": "tools"}


# The import name of each distribution the project declares, where it is not the
# distribution's own name.
_IMPORT_NAME = {"foxglove-sdk": "foxglove", "foxglove-schemas-protobuf":
                "foxglove_schemas_protobuf", "protobuf": "google", "rerun-sdk": "rerun"}
# Modules that are an optional extra's front door: they import it, and say how to install it.
_OPTIONAL_HOMES = {"gymnasium": {"tfl_mav/gym.py"},
                   "ray": {"tools/harness/campaign/executors.py"}}


def _declared(requirements: list[str]) -> set[str]:
    names = set()
    for req in requirements:
        dist = req.split(";")[0].strip()
        for sep in "<>=!~[ ":
            dist = dist.split(sep)[0]
        names.add(_IMPORT_NAME.get(dist, dist.replace("-", "_")))
    return names


def _third_party_imports() -> dict[str, set[str]]:
    """Top-level third-party names imported anywhere in the installed code (function-level
    imports too), with the files that import them."""
    import ast
    import sys

    found: dict[str, set[str]] = {}
    for root in ("tfl_mav", "sitl", "tools"):
        for path in (REPO / root).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top != "tfl_mav":
                        found.setdefault(top, set()).add(path.relative_to(REPO).as_posix())
    return found


def test_the_installed_code_imports_only_what_a_plain_install_brings() -> None:
    """A test extra (scipy, hypothesis, …) imported by the library works in the test venv and
    fails a user's ``pip install tfl-mav``: every third-party import is a runtime dependency,
    or an optional extra imported only by the module that is its front door."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    runtime = _declared(project["dependencies"])
    for name, files in _third_party_imports().items():
        if name in runtime:
            continue
        assert files <= _OPTIONAL_HOMES.get(name, set()), (
            f"{name} is imported by {sorted(files)} but is not a runtime dependency")
