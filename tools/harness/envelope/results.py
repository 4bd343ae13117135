"""One case's measured result, its outcome rule, and the JSON files that keep them.

The same :func:`outcome_of` judges today's flights, the baseline and another tree's
``tfl-mav offline --json`` output, so the columns of the table are comparable. The files
(``baseline.json``, ``reference-<tree>.json``) hold only deterministic numbers (no wall
times), one entry per case keyed by name, with the case's base and overrides so a stale
entry (the case was edited since) is seen instead of compared.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["CONVERGED_MAX_M", "NOT_AVAILABLE", "OUTCOMES", "CaseResult", "ResultsFile",
           "default_baseline_path", "outcome_of", "read_results_file", "reference_files",
           "write_results_file"]

CONVERGED_MAX_M = 0.02      # "converged": ≤ 20 mm over the last 10 s (the metrics default)
OUTCOMES = ("converged", "off-path", "crashed")
ERROR = "error"             # the flight raised or its process died: never a baseline value
NOT_AVAILABLE = "n/a"       # another tree could not fly the case (key, path or signal missing)


def outcome_of(crashed: bool, max_distance_m: float | None) -> str:
    """converged (≤ 20 mm over the last 10 s) / off-path / crashed. A non-finite distance
    (None) is off the path: the vehicle left it so far the distance is not defined."""
    if crashed:
        return "crashed"
    if max_distance_m is not None and math.isfinite(max_distance_m) \
            and max_distance_m <= CONVERGED_MAX_M:
        return "converged"
    return "off-path"


@dataclass
class CaseResult:
    """What one flight of a case did. Distances over the last 10 s of the flight (before
    the crash for a crashed one); ``mode_fraction``: share of control ticks in each mode."""

    name: str
    outcome: str
    max_distance_m: float | None = None
    rms_distance_m: float | None = None
    attack_rotor: int = 0
    detected_rotor: int | None = None           # None: not known (another tree's CLI)
    detection_latency_s: float | None = None
    false_alarms: int | None = None
    mode_fraction: dict[str, float] = field(default_factory=dict)
    thrust_req_min_n: float | None = None
    thrust_req_max_n: float | None = None
    sim_time_s: float | None = None
    reason: str = ""                            # crash reason, error, or why n/a
    wall_time_s: float | None = None            # not written to the files (not deterministic)
    base: str = ""
    settings: tuple[str, ...] = ()
    law_switches: int | None = None             # switches between TFL and the safe law
    # The largest distance to the path from a third of the flight on (past the approach: the
    # paper's 30 s from 10 s) and when (s): where the last 10 s open on a peak, the peak.
    peak_distance_m: float | None = None
    peak_time_s: float | None = None

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("wall_time_s")
        d.pop("name")
        d["settings"] = list(self.settings)
        return d

    @classmethod
    def from_json(cls, name: str, data: dict[str, Any]) -> CaseResult:
        known = {f.name for f in fields(cls)}
        kw = {k: v for k, v in data.items() if k in known}
        kw["settings"] = tuple(kw.get("settings", ()))
        return cls(name=name, **kw)

    @property
    def max_distance_mm(self) -> float | None:
        d = self.max_distance_m
        return None if d is None or not math.isfinite(d) else 1000.0 * d


@dataclass
class ResultsFile:
    """A baseline or reference: what tree flew it, and one result per case."""

    tree: str
    about: str
    results: dict[str, CaseResult]

    def get(self, name: str) -> CaseResult | None:
        return self.results.get(name)


def default_baseline_path() -> Path:
    """The committed baseline next to the spec (the package is installed editable)."""
    return Path(str(resources.files("tfl_mav.tools.harness.envelope").joinpath("baseline.json")))


def reference_files(directory: Path | None = None) -> list[Path]:
    """The committed ``reference-<tree>.json`` columns, in name order."""
    d = directory or default_baseline_path().parent
    return sorted(d.glob("reference-*.json"))


def write_results_file(path: Path, rf: ResultsFile, order: list[str] | None = None) -> None:
    """Write ``rf`` (cases in ``order``, else by name), stable and diffable."""
    names = order if order is not None else sorted(rf.results)
    data = {"tree": rf.tree, "about": rf.about,
            "cases": {n: rf.results[n].to_json() for n in names if n in rf.results}}
    path.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")


def read_results_file(path: Path) -> ResultsFile:
    """Read a baseline/reference; a missing file is an empty one."""
    if not path.exists():
        return ResultsFile(tree="", about="", results={})
    data = json.loads(path.read_text(encoding="utf-8"))
    results = {n: CaseResult.from_json(n, d) for n, d in data.get("cases", {}).items()}
    return ResultsFile(tree=str(data.get("tree", "")), about=str(data.get("about", "")),
                       results=results)
