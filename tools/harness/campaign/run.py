"""One campaign run: fly it, judge it, and keep a hung or crashing run from hurting the rest.

:func:`execute` is the flight itself — ``offline``: exactly
:func:`tfl_mav.offline.fly_offline` + :func:`tfl_mav.flightlog.flight.summarize`, as
``tfl-mav offline --set ...``; ``mavlink``: :func:`tfl_mav.tools.harness.demo.run_demo`, as
``tfl-mav demo --set ...`` — and returns the row of the results table. A run whose
``controller`` is not ``tfl`` flies that software offline through the public API
(:class:`tfl_mav.api.Environment`, as ``tfl-mav compare`` does); the same metrics, and a
controller that raises or returns a bad thrust fails its row with its one-line reason.
:class:`Child` runs it in a forked process of its own session, so a timeout kills the run
*and* whatever it started (the sim and daemon of a MAVLink run), and a segfault is a failed
row. Both executors use it, so the table does not depend on the executor.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import shutil
import signal
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tfl_mav.scenario import Scenario, apply_overrides, load_scenario
from tfl_mav.tools.harness.campaign.spec import DEFAULT_CONTROLLER, SUCCESS_MAX_DISTANCE_M, Run

if TYPE_CHECKING:
    from tfl_mav.flightlog.flight import FlightLog

__all__ = ["RESULT_COLUMNS", "Child", "Target", "execute", "failed_row", "offline_metrics",
           "run_isolated", "run_outcome", "software_metrics"]

# The measured columns of results.csv, after run_id, the swept keys and seed.
RESULT_COLUMNS = ("success", "crashed", "max_path_distance_last_10s_m",
                  "final_path_distance_m", "rms_path_distance_last_10s_m", "detected_rotor",
                  "detection_latency_s", "false_alarms", "thrust_min_n", "thrust_max_n",
                  "saturated_fraction", "sim_time_s", "wall_time_s", "reason")


def run_outcome(metrics: dict[str, Any], scenario: Scenario, *,
                max_distance_m: float = SUCCESS_MAX_DISTANCE_M) -> tuple[bool, str]:
    """Did the run succeed, and if not, why (in words)?

    Not crashed, not interrupted, converged in the sense of
    :func:`tfl_mav.flightlog.metrics.converged` (largest distance to the path over the last
    10 s, at most half the flight) with the campaign's bound ``max_distance_m``,
    and — when the attack was detected from rpm (``detected_rotor`` present) — the detected
    rotor is the attacked one (0 when there is no attack) with no false alarm. A flight
    whose software failed (``failure_reason``) failed for that reason, whatever came after.
    """
    if metrics.get("failure_reason"):
        return False, metrics["failure_reason"]
    if metrics.get("crashed"):
        return False, f"crashed: {metrics.get('crash_reason') or 'no reason logged'}"
    # tfl_mav.flightlog.metrics.converged's window (10 s, at most half the flight) and its
    # max distance, judged at the campaign's bound; older rows: the plain last 10 s.
    if "interrupted" in (metrics.get("convergence") or ""):
        return False, metrics["convergence"]
    dist = metrics.get("convergence_max_distance_m",
                       metrics.get("max_path_distance_last_10s_m"))
    window = metrics.get("convergence_window_s") or 10.0
    if dist is None or not math.isfinite(dist):
        return False, f"the path distance was not finite over the last {window:g} s (path lost)"
    if dist > max_distance_m:
        return False, (f"off the path: {dist:.3g} m max distance over the last {window:g} s "
                       f"> {max_distance_m:g} m")
    if metrics.get("detected_rotor") is not None:
        attacked = scenario.attack.rotor
        detected = int(metrics["detected_rotor"])
        if detected != attacked:
            if not detected:
                return False, f"the attack on rotor {attacked} was not detected"
            if not attacked:
                return False, f"false alarm: rotor {detected} detected, no attack"
            return False, f"wrong rotor: detected {detected}, attacked {attacked}"
        if metrics.get("false_alarms"):
            return False, f"{metrics['false_alarms']} false alarm(s) before the detection"
    return True, ""


def execute(run: Run) -> dict[str, Any]:
    """Fly ``run`` in this process and return its measured columns."""
    t0 = time.perf_counter()
    sc = apply_overrides(load_scenario(run.base), list(run.settings))
    if run.controller != DEFAULT_CONTROLLER:
        fly = _fly_software            # the spec allows other software offline only
    else:
        fly = _fly_offline if run.mode == "offline" else _fly_mavlink
    metrics = fly(sc, run)
    ok, reason = run_outcome(metrics, sc, max_distance_m=run.success_max_distance_m)
    row = {k: metrics.get(k) for k in RESULT_COLUMNS}
    row.update(success=ok, reason=reason, wall_time_s=round(time.perf_counter() - t0, 3))
    return row


def offline_metrics(sc: Scenario, attack_info: str) -> tuple[dict[str, Any], FlightLog]:
    """Fly ``sc`` offline: the ``tfl-mav offline --json`` metrics (detection by the MAVLink
    demo's definition when detected from rpm) and the log they came from."""
    from tfl_mav.flightlog.flight import summarize
    from tfl_mav.flightlog.metrics import detection_from_alarms
    from tfl_mav.offline import detections, fly_offline

    log = fly_offline(sc, attack_info=attack_info)
    metrics = summarize(log)
    if attack_info == "detector":
        # The same definition as the MAVLink demo's (first alarm at or after the attack).
        metrics.update(detection_from_alarms(detections(log), sc.attack.rotor,
                                             sc.attack.start_s))
    return metrics, log


def _fly_offline(sc: Scenario, run: Run) -> dict[str, Any]:
    return offline_metrics(sc, run.attack_info)[0]


def software_metrics(sc: Scenario, controller: str, attack_info: str
                     ) -> tuple[dict[str, Any], FlightLog | None]:
    """Fly ``sc`` offline with the flight software ``controller`` names (``se3``,
    ``module:Name`` …): the metrics of :func:`offline_metrics` and the log they came from,
    plus ``failure_reason`` when the software failed (the flight stopped there).

    The path distance judged is the one the software measured from the state it saw, as for
    TFL rows (:class:`~tfl_mav.controller.software.ControllerSoftware` measures it for a
    controller); software that reports none gets the true distance computed after the flight, rather
    than a row that reads "path lost".
    """
    from tfl_mav.api import Environment
    from tfl_mav.controller.software import load_flight_software
    from tfl_mav.flightlog.flight import summarize
    from tfl_mav.flightlog.metrics import detection_from_alarms
    from tfl_mav.offline import detections

    name, factory = load_flight_software(controller)

    def make(scenario: Scenario) -> Any:
        # A constructor that raises fails the row naming the software, not as a bare
        # TypeError from somewhere inside the run.
        try:
            return factory(scenario)
        except Exception as exc:
            text = " ".join(str(exc).split())
            raise _MakeError(f"{name}: making it raised {type(exc).__name__}: {text}") from None

    try:
        flight = Environment(sc, make, attack_info=attack_info, name=name).fly()
    except _MakeError as exc:
        return {"crashed": False, "failure_reason": str(exc)}, None
    log = flight.log
    dist = log.data.get("path_distance_m")
    if dist is not None and len(dist) and not np.isfinite(dist).any():
        log.data["path_distance_m"] = flight.path_distance_m
    metrics = summarize(log)
    if attack_info == "detector":
        metrics.update(detection_from_alarms(detections(log), sc.attack.rotor,
                                             sc.attack.start_s))
    if flight.failure_reason:
        metrics["failure_reason"] = flight.failure_reason
    return metrics, log


class _MakeError(RuntimeError):
    """The flight software could not be made for the scenario."""


def _fly_software(sc: Scenario, run: Run) -> dict[str, Any]:
    return software_metrics(sc, run.controller, run.attack_info)[0]


def _fly_mavlink(sc: Scenario, run: Run) -> dict[str, Any]:
    from tfl_mav.tools.harness.demo import run_demo

    out = Path(run.out_dir)
    try:
        return run_demo(run.base, out, settings=list(run.settings), plots=False, scenario=sc)
    finally:
        if not run.keep_logs:
            shutil.rmtree(out, ignore_errors=True)


def failed_row(reason: str, wall_time_s: float | None = None) -> dict[str, Any]:
    """The row of a run that produced no metrics (it raised, hung or its process died)."""
    row: dict[str, Any] = dict.fromkeys(RESULT_COLUMNS)
    row.update(success=False, reason=reason, wall_time_s=wall_time_s)
    return row


# What a child computes from its run: :func:`execute` (a results-table row) unless told.
Target = Callable[[Run], dict[str, Any]]


def _child_main(run: Run, conn: Connection, target: Target) -> None:
    os.setsid()          # its own process group: a timeout kills the run and its children
    t0 = time.perf_counter()
    try:
        row = target(run)
    except BaseException as exc:
        text = str(exc).strip().splitlines()
        row = failed_row(f"{type(exc).__name__}: {text[0] if text else 'no message'}",
                         round(time.perf_counter() - t0, 3))
    conn.send(row)
    conn.close()


class Child:
    """One run in a forked process; :meth:`result` is None until it is over. ``target``
    computes the row (default :func:`execute`; the envelope measures more per flight)."""

    def __init__(self, run: Run, target: Target | None = None) -> None:
        ctx = mp.get_context("fork")
        self.run = run
        self.conn, writer = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=_child_main, args=(run, writer, target or execute),
                                daemon=True,
                                name=f"campaign-run-{run.run_id}")
        self.t0 = time.monotonic()
        self.proc.start()
        writer.close()

    @property
    def overdue(self) -> bool:
        return time.monotonic() - self.t0 > self.run.timeout_s

    def result(self) -> dict[str, Any] | None:
        """The row once the child sent it or died, a timeout row once it is overdue."""
        if self.conn.poll():
            try:
                row = self.conn.recv()
            except EOFError:
                self.proc.join(timeout=5)
                row = failed_row(f"the run's process died (exit code {self.proc.exitcode})",
                                 round(time.monotonic() - self.t0, 3))
            self.close()
            return row
        if self.overdue:
            self.kill()
            return failed_row(f"timed out after {self.run.timeout_s:g} s",
                              round(self.run.timeout_s, 3))
        return None

    def kill(self) -> None:
        """Kill the run's whole process group (a MAVLink run's sim and daemon too)."""
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            self.proc.kill()
        self.close()

    def close(self) -> None:
        self.proc.join(timeout=5)
        self.conn.close()


def run_isolated(run: Run) -> dict[str, Any]:
    """Fly ``run`` in a child process with its timeout; always returns a row."""
    child = Child(run)
    try:
        while True:
            left = run.timeout_s - (time.monotonic() - child.t0)
            child.conn.poll(max(0.0, min(left, 1.0)))
            row = child.result()
            if row is not None:
                return row
    except BaseException:
        child.kill()
        raise
