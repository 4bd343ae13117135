"""Campaign specs: a TOML file that names a base scenario and the keys to sweep.

A spec expands into runs: ``variants × grid × random samples × seeds``. Every swept value is
turned into the ``--set KEY=VALUE`` text that ``tfl-mav offline``/``demo`` accept and applied
with :func:`tfl_mav.scenario.apply_overrides` before any run starts, so a bad key fails at
once with the scenario's own one-line error, and a run is the CLI flight with those
``--set`` options by construction.

One key is not the scenario's: ``controller`` (in ``[set]``, ``[grid]`` or ``[[variants]]``)
names the flight software, as ``tfl-mav compare --controllers`` takes it (``tfl``, ``se3``,
``cascade``, ``MODULE:NAME``, ``FILE.py:NAME``; default ``tfl``). It is loaded when the spec
is validated, so an unknown name fails before any run; it never becomes a ``--set`` text.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.controller.software import FlightSoftwareError
from tfl_mav.from_scenario import build_controller
from tfl_mav.scenario import Scenario, ScenarioError, apply_overrides, load_scenario

__all__ = ["CONTROLLER_KEY", "DEFAULT_CONTROLLER", "SUCCESS_MAX_DISTANCE_M", "CampaignSpec",
           "Run", "SpecError", "builtin_specs", "load_spec", "scenario_value", "spec_from_dict",
           "toml_value"]

SUCCESS_MAX_DISTANCE_M = 0.05
# The flight software of a run: a reserved key beside the scenario's dotted keys (a bare
# name, so it cannot collide with the scenario's own [controller] section keys).
CONTROLLER_KEY = "controller"
DEFAULT_CONTROLLER = "tfl"
MODES = ("offline", "mavlink")
ATTACK_INFO = ("detector", "oracle")
_TOP_KEYS = ("name", "description", "base", "mode", "seeds", "duration_s", "attack_info",
             "success_max_distance_m", "timeout_s", "keep_logs", "set", "grid", "random",
             "variants", "report")


class SpecError(ValueError):
    """A malformed campaign spec; the message is one line naming the key at fault."""


@dataclass(frozen=True)
class Run:
    """One flight of a campaign: everything a worker needs, picklable, no scenario object."""

    run_id: str
    base: str
    settings: tuple[str, ...]       # --set KEY=VALUE texts, in order
    values: dict[str, Any]          # the swept columns of this run (dotted key → value)
    seed: int
    mode: str = "offline"
    attack_info: str = "detector"
    timeout_s: float = 600.0
    success_max_distance_m: float = SUCCESS_MAX_DISTANCE_M
    out_dir: str = ""               # mavlink: where run_demo writes its files
    keep_logs: bool = False
    controller: str = DEFAULT_CONTROLLER   # flight software, as `tfl-mav compare` names it


@dataclass(frozen=True)
class CampaignSpec:
    """A validated spec. ``columns``: the swept keys, in table order."""

    name: str
    base: str
    mode: str = "offline"
    seeds: int = 1
    duration_s: float | None = None
    attack_info: str = "detector"
    success_max_distance_m: float = SUCCESS_MAX_DISTANCE_M
    timeout_s: float = 600.0
    keep_logs: bool = False
    fixed: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list[Any]] = field(default_factory=dict)
    random: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    samples: int = 0
    random_seed: int = 0
    variants: list[dict[str, Any]] = field(default_factory=list)
    maps: list[tuple[str, str]] = field(default_factory=list)
    description: str = ""
    source: str = ""
    text: str = ""

    @property
    def columns(self) -> list[str]:
        cols = ["variant"] if self.variants else []
        for v in self.variants:
            cols += [k for k in v if k != "name" and k not in cols]
        cols += [k for k in (*self.grid, *self.random) if k not in cols]
        return cols

    @property
    def fingerprint(self) -> str:
        """Identity of the set of runs (not of how they are executed)."""
        ident = {k: v for k, v in dataclasses.asdict(self).items()
                 if k not in ("text", "source", "description", "maps", "timeout_s")}
        blob = json.dumps(ident, sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def base_scenario(self) -> Scenario:
        return load_scenario(self.base)

    def runs(self, out_dir: Path | None = None) -> list[Run]:
        """Every run, in a fixed order (run_id = its index), values drawn with the spec seed."""
        base = self.base_scenario()
        common = [f"{k}={toml_value(v)}" for k, v in self.fixed.items() if k != CONTROLLER_KEY]
        fixed_controller = self.fixed.get(CONTROLLER_KEY, DEFAULT_CONTROLLER)
        if self.duration_s is not None:
            common.append(f"run.duration_s={toml_value(self.duration_s)}")
        variants = self.variants or [{}]
        grid_keys = list(self.grid)
        grid_points = list(itertools.product(*(self.grid[k] for k in grid_keys)))
        samples = _draw(self.random, self.samples, self.random_seed)
        cols = self.columns
        out: list[Run] = []
        for variant in variants:
            vset = {k: v for k, v in variant.items() if k != "name"}
            for gp in grid_points:
                for sample in samples:
                    point = {**vset, **dict(zip(grid_keys, gp, strict=True)), **sample}
                    controller = point.pop(CONTROLLER_KEY, fixed_controller)
                    settings = common + [f"{k}={toml_value(v)}" for k, v in point.items()]
                    sc = apply_overrides(base, settings)
                    build_controller(sc)     # path and law errors now, not mid-campaign
                    values = {c: controller if c == CONTROLLER_KEY else scenario_value(sc, c)
                              for c in cols if c != "variant"}
                    if self.variants:
                        values = {"variant": variant["name"], **values}
                    for seed in range(self.seeds):
                        rid = f"{len(out):06d}"
                        run_dir = str(out_dir / "runs" / rid) if out_dir else ""
                        out.append(Run(rid, self.base, (*settings, f"run.seed={seed}"), values,
                                       seed, self.mode, self.attack_info, self.timeout_s,
                                       self.success_max_distance_m, run_dir, self.keep_logs,
                                       controller))
        return out


def _draw(ranges: dict[str, tuple[Any, Any]], samples: int, seed: int) -> list[dict[str, Any]]:
    """``samples`` points uniform in the ranges (integers if both bounds are), seeded."""
    if not ranges:
        return [{}]
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(samples):
        point: dict[str, Any] = {}
        for key, (lo, hi) in ranges.items():
            if isinstance(lo, int) and isinstance(hi, int):
                point[key] = int(rng.integers(lo, hi + 1))
            else:
                point[key] = float(rng.uniform(lo, hi))
        out.append(point)
    return out


def toml_value(value: Any) -> str:
    """``value`` as TOML value text that parses back to exactly ``value``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise SpecError(f"cannot write {value!r} as a scenario value")


def scenario_value(sc: Scenario, key: str) -> Any:
    """The value of dotted ``key`` in ``sc`` (path parameters included)."""
    section, _, name = key.partition(".")
    sec = getattr(sc, section)
    if section == "path" and name not in ("kind", "speed_mps"):
        return sec.params.get(name)
    value = getattr(sec, name)
    return list(value) if isinstance(value, tuple) else value


def builtin_specs() -> dict[str, str]:
    """Built-in spec names mapped to their descriptions."""
    out = {}
    root = resources.files("tfl_mav.tools.harness.campaign").joinpath("specs")
    for entry in sorted(root.iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".toml"):
            data = tomllib.loads(entry.read_text(encoding="utf-8"))
            out[entry.name[:-5]] = str(data.get("description", ""))
    return out


def load_spec(name_or_path: str | Path) -> CampaignSpec:
    """A built-in spec by name (``paper-envelope``) or a TOML file; :class:`SpecError` if bad."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise SpecError(f"cannot read spec {str(path)!r}: {exc.strerror}") from None
        source = str(path)
    else:
        res = resources.files("tfl_mav.tools.harness.campaign").joinpath(
            "specs", f"{name_or_path}.toml")
        if not res.is_file():
            raise SpecError(f"no built-in spec {str(name_or_path)!r} and no such file "
                            f"(built-ins: {', '.join(builtin_specs())})")
        text, source = res.read_text(encoding="utf-8"), f"<built-in {name_or_path}>"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{source}: not valid TOML: {exc}") from None
    data.setdefault("name", path.stem)
    return spec_from_dict(data, source=source, text=text)


def _need(cond: bool, key: str, message: str) -> None:
    if not cond:
        raise SpecError(f"{key}: {message}")


def _number(data: dict[str, Any], key: str, default: Any, *, integer: bool = False,
            lo: float = 0.0, lo_open: bool = False) -> Any:
    value = data.get(key, default)
    if value is None:
        return None
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    _need(ok and not isinstance(value, bool), key,
          f"must be {'an integer' if integer else 'a number'}, got {value!r}")
    _need(math.isfinite(value) and (value > lo if lo_open else value >= lo), key,
          f"must be {'>' if lo_open else '>='} {lo:g}, got {value!r}")
    return value if integer else float(value)


def _choice(data: dict[str, Any], key: str, default: str, choices: tuple[str, ...]) -> str:
    value = data.get(key, default)
    _need(value in choices, key, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


def _table(data: dict[str, Any], key: str) -> dict[str, Any]:
    """A table with nested tables flattened to dotted keys (``a.b = 1`` unquoted in TOML)."""
    value = data.get(key, {})
    _need(isinstance(value, dict), key, f"must be a table, got {value!r}")
    return _flatten(value)


def _flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in table.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def spec_from_dict(data: dict[str, Any], *, source: str = "<dict>", text: str = "") -> CampaignSpec:
    """Validate a TOML-shaped spec; every swept value is tried on the base scenario."""
    try:
        return _spec_from_dict(data, source, text)
    except ScenarioError as exc:
        raise SpecError(str(exc)) from None


def _spec_from_dict(data: dict[str, Any], source: str, text: str) -> CampaignSpec:
    for key in data:
        _need(key in _TOP_KEYS, key, f"unknown key (known: {', '.join(_TOP_KEYS)})")
    name = data.get("name", "campaign")
    _need(isinstance(name, str) and bool(name), "name", f"must be a string, got {name!r}")
    base = data.get("base", "paper")
    _need(isinstance(base, str), "base", f"must be a scenario name or path, got {base!r}")
    try:
        sc = load_scenario(base)
    except ScenarioError as exc:
        raise SpecError(f"base: {exc}") from None
    mode = _choice(data, "mode", "offline", MODES)
    attack_info = _choice(data, "attack_info", "detector", ATTACK_INFO)
    _need(not (mode == "mavlink" and attack_info == "oracle"), "attack_info",
          "the MAVLink daemon always detects the attack from rpm; 'oracle' needs mode 'offline'")
    seeds = _number(data, "seeds", 1, integer=True, lo=1)
    duration = _number(data, "duration_s", None, lo=0.0, lo_open=True)
    timeout = _number(data, "timeout_s", 60.0 + 10.0 * (duration or sc.run.duration_s),
                      lo=0.0, lo_open=True)
    keep_logs = data.get("keep_logs", False)
    _need(isinstance(keep_logs, bool), "keep_logs", f"must be true or false, got {keep_logs!r}")

    fixed = _table(data, "set")
    if CONTROLLER_KEY in fixed:
        _check_controller(fixed[CONTROLLER_KEY], "set", mode)
    sc = _check(sc, _scenario_keys(fixed), "set")
    grid = _table(data, "grid")
    for key, values in grid.items():
        _need(isinstance(values, list) and bool(values), f"grid.{key}",
              f"must be a non-empty list of values, got {values!r}")
        for v in values:
            if key == CONTROLLER_KEY:
                _check_controller(v, "grid", mode)
            else:
                _check(sc, {key: v}, "grid")
    rnd = _table(data, "random")
    samples = _number(rnd, "samples", 0, integer=True) if rnd else 0
    rseed = _number(rnd, "seed", 0, integer=True) if rnd else 0
    ranges: dict[str, tuple[Any, Any]] = {}
    for key, bounds in rnd.items():
        if key in ("samples", "seed"):
            continue
        _need(key != CONTROLLER_KEY, f"random.{key}",
              "names flight software, not a number: sweep it in [grid] or [[variants]]")
        _need(isinstance(bounds, list) and len(bounds) == 2
              and all(isinstance(b, (int, float)) and not isinstance(b, bool) for b in bounds)
              and bounds[0] <= bounds[1], f"random.{key}",
              f"must be [lo, hi] with lo <= hi, got {bounds!r}")
        for b in bounds:
            _check(sc, {key: b}, "random")
        ranges[key] = (bounds[0], bounds[1])
    _need(not ranges or samples > 0, "random.samples", "must be > 0 when ranges are given")
    variants = data.get("variants", [])
    _need(isinstance(variants, list) and all(isinstance(v, dict) for v in variants),
          "variants", "must be an array of tables ([[variants]])")
    variants = [_flatten(v) for v in variants]
    names = []
    for i, v in enumerate(variants):
        vname = v.get("name")
        _need(isinstance(vname, str) and vname not in names, f"variants[{i}].name",
              f"must be a unique string, got {vname!r}")
        names.append(vname)
        if CONTROLLER_KEY in v:
            _check_controller(v[CONTROLLER_KEY], f"variants[{i}]", mode)
        _check(sc, _scenario_keys({k: x for k, x in v.items() if k != "name"}), f"variants[{i}]")
    swept = [*grid, *ranges]
    for key in swept:
        _need(key not in fixed, key, "is both fixed ([set]) and swept")
        _need(key != "run.seed", key, "run.seed is set by `seeds`, not swept")
        _need(key != "run.duration_s" or duration is None, key,
              "is swept and also given as duration_s")
    _need(len(set(swept)) == len(swept), "random", "a key is both in [grid] and [random]")
    spec = CampaignSpec(
        name=name, base=base, mode=mode, seeds=seeds, duration_s=duration,
        attack_info=attack_info, timeout_s=timeout, keep_logs=keep_logs,
        success_max_distance_m=_number(data, "success_max_distance_m", SUCCESS_MAX_DISTANCE_M,
                                       lo=0.0, lo_open=True),
        fixed=fixed, grid=grid, random=ranges, samples=samples, random_seed=rseed,
        variants=variants, description=str(data.get("description", "")), source=source,
        text=text)
    report = _table(data, "report")
    for key in report:
        _need(key == "maps", f"report.{key}", "unknown key (known: maps)")
    maps = report.get("maps", [])
    for pair in maps:
        _need(isinstance(pair, list) and len(pair) == 2 and all(k in spec.columns for k in pair),
              "report.maps", f"each map is [KEY, KEY] of swept keys ({', '.join(spec.columns)})"
                             f", got {pair!r}")
    spec = dataclasses.replace(spec, maps=[tuple(p) for p in maps])
    spec.runs()          # every combination must build (e.g. path keys of its path kind)
    return spec


def _scenario_keys(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` without the reserved ``controller`` key (the rest are the scenario's)."""
    return {k: v for k, v in values.items() if k != CONTROLLER_KEY}


def _check_controller(name: Any, where: str, mode: str) -> None:
    """A controller name ``tfl-mav compare`` accepts, loaded now (its import errors too), so
    a typo fails the spec before any run rather than every row of it."""
    key = f"{where}.{CONTROLLER_KEY}"
    _need(isinstance(name, str) and bool(name), key,
          f"must be a controller name (tfl, se3, cascade, MODULE:NAME or FILE.py:NAME), "
          f"got {name!r}")
    # The MAVLink run is `tfl-mav demo`, whose daemon flies the TFL law; handing it other
    # software is not wired, so say so rather than fly TFL under another name.
    _need(mode == "offline" or name == DEFAULT_CONTROLLER, key,
          f"{name!r} needs mode = \"offline\" (a mavlink campaign flies the TFL daemon "
          f"only; fly other software over MAVLink with `tfl-mav fly --controller`)")
    if name == DEFAULT_CONTROLLER:
        return
    from tfl_mav.comparison import check_controllers

    try:
        check_controllers([name])
    except FlightSoftwareError as exc:
        raise SpecError(f"{key}: {exc}") from None


def _check(sc: Scenario, values: dict[str, Any], where: str) -> Scenario:
    """Apply ``values`` as --set texts: the scenario's own validation, one line per error."""
    try:
        settings = [f"{k}={toml_value(v)}" for k, v in values.items()]
    except SpecError as exc:
        raise SpecError(f"{where}: {exc}") from None
    try:
        return apply_overrides(sc, settings)
    except ScenarioError as exc:
        raise SpecError(f"{where}.{exc}" if exc.key else f"{where}: {exc}") from None
