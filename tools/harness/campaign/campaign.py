"""Run a campaign into a directory: what is missing is flown, each row is kept as it lands.

``DIR/campaign.json`` pins the campaign (its fingerprint: the set of runs), so re-running
into the same DIR resumes it and a different spec is refused rather than mixed in.
``DIR/results.csv`` is the table, ``DIR/summary.json`` the counts, and the report (tables
and envelope maps) is redrawn at the end.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from tfl_mav.scenario import ScenarioError
from tfl_mav.tools.harness.campaign.executors import run_local, run_ray
from tfl_mav.tools.harness.campaign.results import (
    ResultsWriter,
    header_for,
    read_results,
    summarize_rows,
    write_json,
)
from tfl_mav.tools.harness.campaign.run import Run
from tfl_mav.tools.harness.campaign.spec import CampaignSpec, SpecError

__all__ = ["CampaignDirError", "Progress", "run_campaign"]


class CampaignDirError(ValueError):
    """``--out`` holds a different campaign."""


class Progress:
    """Runs done, failures, elapsed and ETA on stderr (one line, redrawn on a terminal)."""

    def __init__(self, name: str, total: int, done: int, stream: TextIO | None = None,
                 every_s: float = 5.0) -> None:
        self.name, self.total, self.done0, self.done = name, total, done, done
        self.failed = 0
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.every_s = every_s
        self.t0 = time.monotonic()
        self._last = -1e9

    def update(self, row: dict[str, Any]) -> None:
        self.done += 1
        self.failed += row.get("success") is not True
        now = time.monotonic()
        if self.tty or now - self._last >= self.every_s or self.done == self.total:
            self._last = now
            self.stream.write(("\r" if self.tty else "") + self.line(now)
                              + ("" if self.tty else "\n"))
            self.stream.flush()

    def line(self, now: float) -> str:
        elapsed = now - self.t0
        flown = self.done - self.done0
        left = self.total - self.done
        eta = elapsed / flown * left if flown else float("nan")
        return (f"campaign {self.name}: {self.done}/{self.total} runs, {self.failed} failed "
                f"this session, {_hms(elapsed)} elapsed, ETA {_hms(eta)}   ")

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")


def _hms(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    n = round(s)
    return f"{n // 3600}:{n // 60 % 60:02d}:{n % 60:02d}"


def run_campaign(spec: CampaignSpec, out: Path, *, executor: str = "local",
                 workers: int | None = None, ray_address: str | None = None,
                 progress: bool = True, report: bool = True,
                 stop: Callable[[], bool] | None = None) -> dict[str, Any]:
    """Fly what ``out`` is missing of ``spec``; returns the summary (also summary.json).
    Interrupted (KeyboardInterrupt, or ``stop()`` true between runs), it returns the summary
    and report of the runs that finished, with ``interrupted`` True (the next call
    resumes)."""
    out.mkdir(parents=True, exist_ok=True)
    meta_path = out / "campaign.json"
    meta = {"name": spec.name, "fingerprint": spec.fingerprint, "source": spec.source,
            "base": spec.base, "mode": spec.mode, "attack_info": spec.attack_info,
            "columns": spec.columns, "maps": [list(m) for m in spec.maps],
            "success_max_distance_m": spec.success_max_distance_m}
    if meta_path.exists():
        old = json.loads(meta_path.read_text(encoding="utf-8"))
        if old.get("fingerprint") != spec.fingerprint:
            raise CampaignDirError(f"--out {out}: holds campaign {old.get('name')!r} with "
                                   f"different runs; use another directory")
    write_json(meta_path, meta)
    if spec.text:
        (out / "spec.toml").write_text(spec.text, encoding="utf-8")
    try:
        runs = spec.runs(out)
    except (ScenarioError, ValueError) as exc:   # e.g. the base file is gone since loading
        raise SpecError(str(exc)) from None
    header = header_for(spec.columns)
    try:
        writer = ResultsWriter(out / "results.csv", header)
    except ValueError as exc:
        raise CampaignDirError(str(exc)) from None
    _, done_rows = read_results(out / "results.csv")
    done = {r["run_id"] for r in done_rows}
    todo = [r for r in runs if r.run_id not in done]
    workers = workers or os.cpu_count() or 1
    bar = Progress(spec.name, len(runs), len(runs) - len(todo)) if progress else None

    def on_row(run: Run, row: dict[str, Any]) -> None:
        writer.write({"run_id": run.run_id, **run.values, "seed": run.seed, **row})
        if bar:
            bar.update(row)

    t0 = time.perf_counter()
    extra: dict[str, Any] = {}
    interrupted = False
    try:
        if executor == "local":
            run_local(todo, workers, on_row, stop=stop)
        elif executor == "ray":
            extra = run_ray(todo, workers, on_row, ray_address, stop=stop)
        else:
            raise SpecError(f"executor: must be local or ray, got {executor!r}")
    except KeyboardInterrupt:
        # Ctrl-C (or SIGTERM, turned into this by the CLI): the runs that finished are in
        # results.csv; the summary and the report below are of them, so an hour of flights
        # is not left without its table.
        interrupted = True
    finally:
        writer.close()
        if bar:
            bar.close()
    wall = time.perf_counter() - t0
    _, rows = read_results(out / "results.csv")
    flown = len(rows) - (len(runs) - len(todo))
    summary = {"name": spec.name, **summarize_rows(rows), "executor": executor,
               "workers": workers, **extra, "flown_now": flown,
               "resumed_from": len(runs) - len(todo), "wall_time_s": round(wall, 3),
               "flights_per_hour": round(3600 * flown / wall, 1) if flown and wall else None,
               "success_max_distance_m": spec.success_max_distance_m, "mode": spec.mode,
               "attack_info": spec.attack_info, "interrupted": interrupted,
               "not_flown": len(runs) - len(rows)}
    write_json(out / "summary.json", summary)
    if report:
        from tfl_mav.tools.harness.campaign.report import write_report

        summary["report"] = [str(p) for p in write_report(out, summary["not_flown"])]
    return summary
