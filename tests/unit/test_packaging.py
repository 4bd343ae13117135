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
