"""Fly envelope cases on this tree: a pool of forked processes, one flight each.

The pool is the campaign's (:func:`tfl_mav.tools.harness.campaign.executors.run_local`: a hung or
crashing flight is a row, not a dead pool), and the flight is the campaign's offline flight
(:func:`tfl_mav.tools.harness.campaign.run.offline_metrics`, i.e. ``tfl-mav offline --json``), so a
case's numbers are the CLI's numbers. Here a flight also reports the share of ticks in each law
mode. Every flight is deterministic (seeded noise), so the result does not depend on the
number of workers or the order they finish in.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tfl_mav.model.modes import Mode
from tfl_mav.tools.harness.campaign.executors import run_local
from tfl_mav.tools.harness.campaign.run import Run, offline_metrics
from tfl_mav.tools.harness.envelope.results import ERROR, NOT_AVAILABLE, CaseResult, outcome_of
from tfl_mav.tools.harness.envelope.spec import Case, case_scenario

__all__ = ["case_run", "default_jobs", "fly_case", "fly_cases", "mode_fractions",
           "peak_after_approach", "print_progress"]

OnResult = Callable[[int, int, CaseResult], None]
TIMEOUT_S = 900.0       # a 120 s flight takes ~10 s on an idle core


def default_jobs() -> int:
    """One flight per core (2 on the project's machines)."""
    return max(1, os.cpu_count() or 2)


def mode_fractions(mode: np.ndarray) -> dict[str, float]:
    """Share of control ticks in each mode, by the mode's name (only modes flown)."""
    m = np.asarray(mode, dtype=float)
    if not len(m):
        return {}
    values, counts = np.unique(m.astype(int), return_counts=True)
    out = {}
    for v, c in zip(values, counts, strict=True):
        try:
            name = str(Mode(int(v)))
        except ValueError:
            name = f"mode-{int(v)}"
        out[name] = round(float(c) / len(m), 6)
    return out


def case_run(case: Case) -> Run:
    """The case as a campaign run (what the pool schedules)."""
    return Run(run_id=case.name, base=case.base, settings=case.settings, values={}, seed=0,
               attack_info="detector", timeout_s=TIMEOUT_S)


def _measure(run: Run) -> dict[str, Any]:
    """The pool's target: fly one case in the child, return its result as a dict."""
    case = Case(run.run_id, "", run.base, run.settings)
    return _to_result(case, *offline_metrics(case_scenario(case), "detector")).__dict__


def peak_after_approach(t_s: Any, distance_m: Any, duration_s: float
                        ) -> tuple[float | None, float | None]:
    """The largest finite distance to the path (m) from a third of ``duration_s`` on, and
    its time (s); (None, None) where the flight has no finite distance there (it ended
    before, or held a point)."""
    t = np.asarray(t_s, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    keep = (t >= duration_s / 3.0) & np.isfinite(d)
    if not keep.any():
        return None, None
    k = int(np.argmax(np.where(keep, d, -np.inf)))
    return float(d[k]), round(float(t[k]), 6)


def _to_result(case: Case, m: dict[str, Any], log: Any) -> CaseResult:
    dist = m.get("max_path_distance_last_10s_m")
    sc = case_scenario(case)
    peak, peak_t = peak_after_approach(log["t_s"], log["path_distance_m"], sc.run.duration_s)
    return CaseResult(
        name=case.name, outcome=outcome_of(bool(m.get("crashed")), dist),
        max_distance_m=dist, rms_distance_m=m.get("rms_path_distance_last_10s_m"),
        attack_rotor=sc.attack.rotor,
        detected_rotor=m.get("detected_rotor"),
        detection_latency_s=m.get("detection_latency_s"),
        false_alarms=m.get("false_alarms"), mode_fraction=mode_fractions(log["mode"]),
        thrust_req_min_n=m.get("thrust_min_n"), thrust_req_max_n=m.get("thrust_max_n"),
        sim_time_s=m.get("sim_time_s"), reason=m.get("crash_reason") or "",
        wall_time_s=m.get("wall_time_s"), base=case.base, settings=case.settings,
        law_switches=m.get("law_switches"), peak_distance_m=peak, peak_time_s=peak_t)


def fly_case(case: Case) -> CaseResult:
    """Fly one case in this process (benches and single checks)."""
    return _to_result(case, *offline_metrics(case_scenario(case), "detector"))


def fly_cases(cases: Sequence[Case], *, jobs: int | None = None,
              on_result: OnResult | None = None) -> dict[str, CaseResult]:
    """Fly ``cases``, ``jobs`` at a time (longest first, so the pool does not end on one
    long flight); returns results keyed by case name."""
    by_name = {c.name: c for c in cases}
    order = sorted(cases, key=lambda c: -c.duration_s)
    out: dict[str, CaseResult] = {}

    def on_row(run: Run, row: dict[str, Any]) -> None:
        case = by_name[run.run_id]
        if "outcome" in row:
            result = CaseResult(**row)
        else:   # the pool's own row: the flight raised, timed out or its process died
            result = CaseResult(name=case.name, outcome=ERROR, reason=str(row.get("reason")),
                                attack_rotor=case.attack_rotor, base=case.base,
                                settings=case.settings, wall_time_s=row.get("wall_time_s"))
        out[case.name] = result
        if on_result:
            on_result(len(out), len(order), result)

    run_local([case_run(c) for c in order], jobs or default_jobs(), on_row, target=_measure)
    return out


def print_progress(i: int, n: int, r: CaseResult) -> None:
    """``[37/130] paper-lag20-pp 0.940 mm converged ... 1.2 s`` on stderr."""
    from tfl_mav.tools.harness.envelope.report import result_text

    what = result_text(r)
    if r.outcome in (ERROR, NOT_AVAILABLE):
        what += f": {r.reason[:80]}"
    print(f"[{i}/{n}] {r.name} {what} ... {r.wall_time_s or 0:.1f} s", file=sys.stderr,
          flush=True)
