"""Where runs fly: ``local`` (forked processes on this machine) or ``ray`` (Ray tasks).

Both hand each run to :class:`tfl_mav.tools.harness.campaign.run.Child` (a forked process with the
run's timeout), so only the scheduling differs and the table is the same. Rows are handed to
``on_row`` in the calling thread as runs finish, in completion order.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from multiprocessing.connection import wait
from typing import Any

from tfl_mav.tools.harness.campaign.run import Child, Run, Target, failed_row, run_isolated

__all__ = ["EXECUTORS", "ExecutorError", "run_local", "run_ray"]

EXECUTORS = ("local", "ray")
OnRow = Callable[[Run, dict[str, Any]], None]


class ExecutorError(RuntimeError):
    """The executor could not start (Ray missing, cluster unreachable)."""


def run_local(runs: Sequence[Run], workers: int, on_row: OnRow,
              target: Target | None = None,
              stop: Callable[[], bool] | None = None) -> None:
    """At most ``workers`` runs at a time, each in its own forked process (``target``: what
    the process computes, :func:`tfl_mav.tools.harness.campaign.run.execute` by default).
    ``stop``: asked between waits (every 0.25 s at most); true stops as Ctrl-C does
    (KeyboardInterrupt, the live runs killed). A signal handler sets what it reads: an
    exception raised from the handler itself is dropped when it lands in a fork's at-fork
    callback."""
    pending = deque(runs)
    live: list[Child] = []
    try:
        while pending or live:
            if stop is not None and stop():
                raise KeyboardInterrupt
            while pending and len(live) < workers:
                live.append(Child(pending.popleft(), target))
            wait([c.conn for c in live], timeout=0.25)
            for child in list(live):
                row = child.result()
                if row is not None:
                    live.remove(child)
                    on_row(child.run, row)
    finally:
        for child in live:
            child.kill()


def run_ray(runs: Sequence[Run], workers: int | None, on_row: OnRow,
            address: str | None = None,
            stop: Callable[[], bool] | None = None) -> dict[str, Any]:
    """Runs as Ray tasks (one CPU each). Joins ``address``, else starts a local Ray instance
    with ``workers`` CPUs (shut down at the end). Returns facts about the cluster."""
    try:
        import ray
    except ImportError:
        raise ExecutorError("the ray executor needs Ray: pip install 'tfl-mav[ray]'") from None
    started = not ray.is_initialized()
    if started:
        try:
            if address:
                ray.init(address=address, logging_level="WARNING", log_to_driver=False)
            else:
                ray.init(num_cpus=workers, include_dashboard=False, logging_level="WARNING",
                         log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise ExecutorError(f"cannot start Ray ({address or 'local'}): {exc}") from None
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        window = max(1, min(workers or cpus, cpus))
        remote = ray.remote(num_cpus=1, max_retries=0)(run_isolated)
        pending = deque(runs)
        inflight: dict[Any, Run] = {}
        try:
            while pending or inflight:
                if stop is not None and stop():
                    raise KeyboardInterrupt
                while pending and len(inflight) < window:
                    run = pending.popleft()
                    inflight[remote.remote(run)] = run
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=0.25)
                for ref in ready:
                    run = inflight.pop(ref)
                    t0 = time.monotonic()
                    try:
                        row = ray.get(ref)
                    except Exception as exc:
                        text = str(exc).strip().splitlines()
                        row = failed_row(f"Ray task failed: {type(exc).__name__}: "
                                         f"{text[0] if text else ''}",
                                         round(time.monotonic() - t0, 3))
                    on_row(run, row)
        finally:
            for ref in inflight:
                ray.cancel(ref, force=True)
        return {"ray_cpus": cpus, "ray_address": address or "local"}
    finally:
        if started:
            ray.shutdown()
