"""The envelope spec (``cases.toml``): families of offline flights, each a base + ``--set``s.

A case is exactly the flight ``tfl-mav offline BASE --set ... --attack-info detector`` flies,
so the same text can be handed to another tree's CLI (the reference column) and the numbers
compare. Loading validates every case with the scenario's own parser
(:func:`tfl_mav.scenario.apply_overrides`, then the path library), so a bad key fails before
anything flies, with one line naming the case and the key.
"""

from __future__ import annotations

import fnmatch
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from tfl_mav.scenario import (
    Scenario,
    ScenarioError,
    apply_overrides,
    builtin_scenarios,
    load_scenario,
)

__all__ = ["DEFAULT_SPEC", "Case", "EnvelopeSpec", "EnvelopeSpecError", "Family",
           "case_scenario", "load_envelope"]

DEFAULT_SPEC = "cases.toml"
_FAMILY_KEYS = ("name", "title", "base", "set", "duration_s", "case")
_CASE_KEYS = ("name", "base", "set", "duration_s", "note", "bound_m")


class EnvelopeSpecError(ValueError):
    """A malformed envelope spec: one line naming the file, the case and the key."""


@dataclass(frozen=True)
class Family:
    """A group of cases shown as one row of the README table."""

    name: str
    title: str


@dataclass(frozen=True)
class Case:
    """One flight: ``settings`` are the ``--set KEY=VALUE`` texts, family's first."""

    name: str
    family: str
    base: str
    settings: tuple[str, ...]
    note: str = ""
    bound_m: float | None = None     # a target shown beside the result; never judged

    @property
    def attack_rotor(self) -> int:
        return case_scenario(self).attack.rotor

    @property
    def duration_s(self) -> float:
        return case_scenario(self).run.duration_s

    def offline_args(self) -> list[str]:
        """The ``tfl-mav offline`` arguments that fly this case."""
        args = [self.base]
        for item in self.settings:
            args += ["--set", item]
        return [*args, "--attack-info", "detector", "--json"]


@dataclass(frozen=True)
class EnvelopeSpec:
    families: tuple[Family, ...]
    cases: tuple[Case, ...]
    source: str = ""

    def select(self, pattern: str | None) -> list[Case]:
        """Cases whose name matches the shell glob ``pattern`` (all when None)."""
        if not pattern:
            return list(self.cases)
        return [c for c in self.cases if fnmatch.fnmatchcase(c.name, pattern)]

    def family(self, name: str) -> Family:
        return next(f for f in self.families if f.name == name)


_SCENARIO_CACHE: dict[tuple[str, tuple[str, ...]], Scenario] = {}


def case_scenario(case: Case) -> Scenario:
    """The case's scenario (validated; cached, as a scenario is frozen)."""
    key = (case.base, case.settings)
    sc = _SCENARIO_CACHE.get(key)
    if sc is None:
        sc = apply_overrides(load_scenario(case.base), list(case.settings))
        _SCENARIO_CACHE[key] = sc
    return sc


def _fail(where: str, message: str) -> EnvelopeSpecError:
    return EnvelopeSpecError(f"{where}: {message}")


def _str(table: dict[str, Any], key: str, where: str, default: str | None = None) -> str:
    value = table.get(key, default)
    if not isinstance(value, str) or not value:
        raise _fail(where, f"{key} must be a non-empty string, got {value!r}")
    return value


def _settings(table: dict[str, Any], where: str) -> list[str]:
    value = table.get("set", [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise _fail(where, f'set must be a list of "KEY=VALUE" strings, got {value!r}')
    return list(value)


def _duration(table: dict[str, Any], where: str) -> list[str]:
    if "duration_s" not in table:
        return []
    value = table["duration_s"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise _fail(where, f"duration_s must be a number > 0, got {value!r}")
    return [f"run.duration_s={float(value)!r}"]


def _unknown(table: dict[str, Any], known: tuple[str, ...], where: str) -> None:
    for key in table:
        if key not in known:
            raise _fail(where, f"unknown key {key!r} (known: {', '.join(known)})")


def spec_from_dict(data: dict[str, Any], source: str = "<dict>", *,
                   validate: bool = True) -> EnvelopeSpec:
    """Build (and with ``validate``, check every case's scenario) from the TOML dict."""
    _unknown(data, ("family",), source)
    raw_families = data.get("family")
    if not isinstance(raw_families, list) or not raw_families:
        raise _fail(source, "expected [[family]] tables")
    builtins = builtin_scenarios()
    families: list[Family] = []
    cases: list[Case] = []
    seen: set[str] = set()
    for i, fam in enumerate(raw_families):
        where = f"{source}: family #{i + 1}"
        if not isinstance(fam, dict):
            raise _fail(where, "must be a table")
        _unknown(fam, _FAMILY_KEYS, where)
        fname = _str(fam, "name", where)
        where = f"{source}: family {fname!r}"
        if any(f.name == fname for f in families):
            raise _fail(where, "family name used twice")
        families.append(Family(fname, _str(fam, "title", where)))
        fam_set = _settings(fam, where) + _duration(fam, where)
        raw_cases = fam.get("case")
        if not isinstance(raw_cases, list) or not raw_cases:
            raise _fail(where, "has no [[family.case]]")
        for raw in raw_cases:
            if not isinstance(raw, dict):
                raise _fail(where, "a case must be a table")
            cname = _str(raw, "name", where)
            cwhere = f"{source}: case {cname!r}"
            _unknown(raw, _CASE_KEYS, cwhere)
            if cname in seen:
                raise _fail(cwhere, "case name used twice")
            seen.add(cname)
            base = _str(raw, "base", cwhere, fam.get("base"))
            if base not in builtins:
                raise _fail(cwhere, f"base {base!r} is not a built-in scenario (known: "
                                    f"{', '.join(builtins)})")
            bound = raw.get("bound_m")
            if bound is not None and (isinstance(bound, bool)
                                      or not isinstance(bound, (int, float))
                                      or not math.isfinite(bound) or bound <= 0):
                raise _fail(cwhere, f"bound_m must be a number > 0, got {bound!r}")
            note = raw.get("note", "")
            if not isinstance(note, str):
                raise _fail(cwhere, f"note must be a string, got {note!r}")
            settings = tuple(fam_set + _settings(raw, cwhere) + _duration(raw, cwhere))
            case = Case(cname, fname, base, settings, note,
                        None if bound is None else float(bound))
            if validate:
                _validate(case, cwhere)
            cases.append(case)
    return EnvelopeSpec(tuple(families), tuple(cases), source)


def _validate(case: Case, where: str) -> None:
    """The case's overrides and path, checked by the scenario's own parser."""
    from tfl_mav.from_scenario import scenario_path

    try:
        scenario_path(case_scenario(case))
    except (ScenarioError, TypeError) as exc:
        raise _fail(where, str(exc)) from None


def load_envelope(path: str | Path | None = None, *, validate: bool = True) -> EnvelopeSpec:
    """The spec at ``path``, or the packaged ``tools/harness/envelope/cases.toml``."""
    if path is None:
        res = resources.files("tfl_mav.tools.harness.envelope").joinpath(DEFAULT_SPEC)
        text, source = res.read_text(encoding="utf-8"), DEFAULT_SPEC
    else:
        source = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise EnvelopeSpecError(f"cannot read envelope spec {source!r}: "
                                    f"{exc.strerror}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise EnvelopeSpecError(f"{source}: not valid TOML: {exc}") from None
    return spec_from_dict(data, source, validate=validate)
